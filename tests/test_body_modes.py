"""Several car-body modes at once (issue 25) against physics computed here: a channel at
angle theta on a body that bounces (vertical z) and pitches (angle phi) reads
g sin(theta + phi) + z sin(theta), so a bounce or bending mode of RMS a shows on it as
a |sin(theta)| and a pitch mode of RMS phi as g cos(theta) phi; a board lever_m ahead of
the pitch centre also rises by L phi, so z gains L phi'' ~ L (2 pi fn)^2 phi. Each mode's
power sits around its natural frequency: for a lightly damped oscillator (|R|^2 nearly a
Lorentzian of half width zeta fn) the share of the mode's band fn (1 +- 6 zeta) within
fn (1 +- zeta) is atan(1) / atan(6) = 0.559. Amplitudes scale with (|v| / v_ref)^n and
vanish at standstill. Frames are decoded with protocol.can_codec."""

from __future__ import annotations

import math
from textwrap import dedent

import numpy as np
import pytest

from devices.emulator import parse_scenario, simulate
from devices.errors import ConfigError
from protocol.layout import G0, NOMINAL_SCALE
from protocol.records import AdcSample
from tests.helpers import records

RATE = 100
S30, C30 = math.sin(math.radians(30.0)), math.cos(math.radians(30.0))
DEG = math.pi / 180.0


def run(
    modes: str,
    *,
    speed: float = 20.0,
    duration: float = 120.0,
    rate: int = RATE,
    filtered: bool = False,
    seed: int = 3,
) -> np.ndarray:
    """(n, 3) accelerations of a level run at constant speed with these [body_modes] keys
    (channels at the nominal +30, 0, -30 deg; no other body motion: no pitch on the
    suspension, no standstill hum)."""
    text = dedent(
        f"""
        duration_s = {duration}
        sample_rate_hz = {rate}
        seed = {seed}
        initial_speed_mps = {speed}
        [board]
        antialias_filter = {str(filtered).lower()}
        [body_pitch]
        enabled = false
        [standstill]
        enabled = false
        """
    ) + dedent(modes)
    sim = simulate(parse_scenario(text, "modes.toml"))
    rows = [rec.code * NOMINAL_SCALE for rec in records(sim.frames) if isinstance(rec, AdcSample)]
    return np.array(rows).reshape(-1, 3)


def only(name: str, rms: float, fn: float, zeta: float, extra: str = "") -> str:
    """[body_modes] with one mode on and the two others at zero RMS."""
    unit = {"bounce": "rms_mps2", "pitch": "rms_deg", "bending": "rms_mps2"}
    out = ["[body_modes]", extra]
    for m in ("bounce", "pitch", "bending"):
        out.append(f"[body_modes.{m}]")
        if m == name:
            out += [f"{unit[m]} = {rms}", f"frequency_hz = {fn}", f"damping = {zeta}"]
        else:
            out.append(f"{unit[m]} = 0.0")
    return "\n".join(out) + "\n"


def rms(x: np.ndarray) -> float:
    x = x - x.mean()
    return float(np.sqrt(np.mean(x * x)))


def band_rms(x: np.ndarray, lo: float, hi: float, rate: int = RATE) -> float:
    """RMS of x's content in [lo, hi] Hz (Parseval over the periodogram)."""
    spec = np.fft.rfft(x - x.mean())
    f = np.fft.rfftfreq(len(x), 1.0 / rate)
    inside = (f >= lo) & (f <= hi)
    return float(np.sqrt(2.0 * np.sum(np.abs(spec[inside]) ** 2)) / len(x))


def test_a_bounce_mode_is_seen_by_each_channel_as_its_rms_times_sin_theta():
    acc = run(only("bounce", 0.1, 1.2, 0.05), speed=10.0)
    k = 10.0 / 20.0  # (v / v_ref)^1 at the default reference 20 m/s
    assert rms(acc[:, 0]) == pytest.approx(0.1 * k * S30, rel=0.1)  # 0.025 m/s^2
    assert rms(acc[:, 2]) == pytest.approx(0.1 * k * S30, rel=0.1)
    assert rms(acc[:, 1]) <= NOMINAL_SCALE  # the along-track axis feels no bounce
    assert np.corrcoef(acc[:, 0], acc[:, 2])[0, 1] < -0.999  # +30 and -30: opposite signs
    # its power lies around 1.2 Hz: 55.9 % of the band 0.84..1.56 Hz within 1.14..1.26 Hz
    z = acc[:, 0]
    share = band_rms(z, 1.14, 1.26) ** 2 / band_rms(z, 0.84, 1.56) ** 2
    assert 0.45 < share < 0.67
    spec = np.abs(np.fft.rfft(z - z.mean())) ** 2
    f = np.fft.rfftfreq(len(z), 1.0 / RATE)
    assert float(np.sum(f * spec) / np.sum(spec)) == pytest.approx(1.2, rel=0.02)


def test_a_pitch_mode_turns_every_axis_g_cos_theta_phi():
    acc = run(only("pitch", 0.05, 1.7, 0.05))
    phi = 0.05 * DEG  # rad RMS at the reference speed
    assert rms(acc[:, 1]) == pytest.approx(G0 * phi, rel=0.1)  # 8.56e-3 m/s^2
    assert rms(acc[:, 0]) == pytest.approx(G0 * C30 * phi, rel=0.1)  # 7.41e-3 m/s^2
    assert rms(acc[:, 2]) == pytest.approx(G0 * C30 * phi, rel=0.1)
    assert np.corrcoef(acc[:, 0], acc[:, 2])[0, 1] > 0.999  # the pair turns together
    x = acc[:, 1]
    share = band_rms(x, 1.615, 1.785) ** 2 / band_rms(x, 1.19, 2.21) ** 2
    assert 0.45 < share < 0.67


def test_a_board_ahead_of_the_pitch_centre_rises_by_lever_times_phi():
    acc = run(only("pitch", 0.05, 1.7, 0.02, "lever_m = 2.0"))
    z = (acc[:, 0] - acc[:, 2]) / (2.0 * S30)  # the vertical specific force
    want = 2.0 * (2 * math.pi * 1.7) ** 2 * 0.05 * DEG  # L wn^2 phi = 0.199 m/s^2
    assert rms(z) == pytest.approx(want, rel=0.1)
    assert rms(acc[:, 1]) == pytest.approx(G0 * 0.05 * DEG, rel=0.1)  # the angle as before


def test_bounce_pitch_and_bending_at_once_each_in_its_own_band():
    modes = """
        [body_modes.bounce]
        rms_mps2 = 0.08
        frequency_hz = 1.0
        damping = 0.03
        [body_modes.pitch]
        rms_deg = 0.04
        frequency_hz = 1.8
        damping = 0.03
        [body_modes.bending]
        rms_mps2 = 0.05
        frequency_hz = 9.0
        damping = 0.03
    """
    acc = run(modes)
    phi = 0.04 * DEG
    # bands fn (1 +- 6 zeta): 0.82..1.18, 1.48..2.12, 7.38..10.62 Hz, well apart
    bounce, pitch, bending = (0.81, 1.19), (1.47, 2.13), (7.3, 10.7)
    for ch, theta in ((0, 30.0), (1, 0.0), (2, -30.0)):
        s, c = abs(math.sin(math.radians(theta))), math.cos(math.radians(theta))
        x = acc[:, ch]
        assert band_rms(x, *bounce) == pytest.approx(0.08 * s, rel=0.1, abs=3e-4)  # z phi, leakage
        assert band_rms(x, *pitch) == pytest.approx(G0 * c * phi, rel=0.1)
        assert band_rms(x, *bending) == pytest.approx(0.05 * s, rel=0.1, abs=3e-4)  # z phi, leakage
        total = math.sqrt((0.08 * s) ** 2 + (G0 * c * phi) ** 2 + (0.05 * s) ** 2)
        assert rms(x) == pytest.approx(total, rel=0.1)
    # the modes add: the three together are the sum of each alone (one draw, any RMS), but
    # for the pitched axes seeing the vertical motion, z sin(phi), and g (1 - cos(phi)):
    # at most |z| |phi| + g phi^2 / 2
    runs = {
        m: run(only(m, r, f, 0.03))
        for m, r, f in (("bounce", 0.08, 1.0), ("pitch", 0.04, 1.8), ("bending", 0.05, 9.0))
    }
    level = run(only("bounce", 0.0, 1.2, 0.03))  # no mode at all: the channels' statics
    alone = sum(runs.values()) - 2 * level
    vert = runs["bounce"] + runs["bending"] - 2 * level
    z = np.abs(vert[:, 0] - vert[:, 2]) / (2 * S30)
    phi_peak = np.abs(runs["pitch"][:, 1]).max() / G0
    bound = z * phi_peak + G0 * phi_peak**2 / 2 + 3 * NOMINAL_SCALE
    assert (np.abs(acc - alone).max(axis=1) <= bound).all()
    assert np.abs(acc - alone).max() > 0.0  # (the cross term exists)


@pytest.mark.parametrize(("speed", "exponent", "k"), [(10.0, 1.0, 0.5), (10.0, 2.0, 0.25)])
def test_the_modes_scale_with_speed(speed: float, exponent: float, k: float):
    keys = only("bounce", 0.1, 1.2, 0.05, f"speed_exponent = {exponent}")
    ref = run(keys, duration=30.0)
    slow = run(keys, duration=30.0, speed=speed)
    z_ref = (ref[:, 0] - ref[:, 2]) / (2 * S30) - G0
    z_slow = (slow[:, 0] - slow[:, 2]) / (2 * S30) - G0
    assert np.abs(z_slow - k * z_ref).max() <= 3 * NOMINAL_SCALE  # the same tones, times k


def test_no_mode_at_standstill():
    acc = run("", speed=0.0, duration=10.0)  # the defaults
    assert (acc == acc[0]).all()


def test_on_by_default_with_documented_amplitudes():
    acc = run("", duration=60.0)  # defaults at the reference speed: 0.06, 0.01 deg, 0.04
    phi = 0.01 * DEG
    assert rms(acc[:, 1]) == pytest.approx(G0 * phi, rel=0.15)  # 1.7e-3 m/s^2
    z = (acc[:, 0] - acc[:, 2]) / (2 * S30)
    assert rms(z) == pytest.approx(math.hypot(0.06, 0.04), rel=0.15)  # 0.072 m/s^2
    off = run("[body_modes]\nenabled = false\n", duration=5.0)
    assert (off == off[0]).all()


def test_the_board_filters_a_bending_mode_as_its_sinc3_decimator_does():
    keys = only("bending", 0.05, 9.0, 0.01)
    raw = run(keys, rate=50, duration=60.0)
    kept = run(keys, rate=50, duration=60.0, filtered=True)
    m, r = 64, 9.0 / 50.0
    h = abs(math.sin(math.pi * r) / (m * math.sin(math.pi * r / m))) ** 3  # 0.850
    assert rms(kept[:, 0]) / rms(raw[:, 0]) == pytest.approx(h, rel=0.02)


@pytest.mark.parametrize(
    "keys",
    [
        "[body_modes]\nbogus = 1\n",
        "[body_modes.bounce]\nrms_mps2 = -0.1\n",
        "[body_modes.pitch]\nrms_mps2 = 0.1\n",  # pitch is in degrees
        "[body_modes.bending]\ndamping = 0.0\n",
        "[body_modes]\nreference_speed_mps = 0.0\n",
    ],
)
def test_bad_keys_are_config_errors(keys: str):
    with pytest.raises(ConfigError):
        run(keys, duration=1.0)
