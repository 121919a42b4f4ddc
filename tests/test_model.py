"""The explicit model (bench.fusion.model): each f/h against a plain-numpy reference written
from the physics, each Jacobian against finite differences, the Joseph update against the
textbook form, and the RTS smoother against the dense least-squares posterior of a linear
Gaussian model (exact for it)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from bench.fusion.model import ekf, jump, linalg, measure, process, smoother, state
from bench.fusion.model.state import B1, B2, B3, NX, TB, TW, A, C, E, K, L, P, S, V

G = 9.80665
THETA = np.radians([-30.0, 0.0, 30.0])  # a plausible mounting, not the code's default
COS, SIN = np.cos(THETA), np.sin(THETA)


def _prm(**kw: float) -> np.ndarray:
    return state.ModelParams(**kw).array()


def _x(
    v: float = 12.0,
    a: float = 0.4,
    s: float = 0.15,
    k: float = 2e-4,
    e: float = 0.02,
    b: tuple[float, float, float] = (1e-3, -2e-3, 5e-4),
    lat: float = 0.0,
    pitch: float = 0.0,
    comp: float = 0.0,
    body: tuple[float, float] = (0.0, 0.0),
) -> np.ndarray:
    x = np.zeros(NX)
    x[V], x[A], x[S], x[K], x[E] = v, a, s, k, e
    x[B1], x[B2], x[B3] = b
    x[L] = lat
    x[P] = pitch
    x[C] = comp
    x[TB], x[TW] = body
    return x


def _numeric_jacobian(fn, x: np.ndarray, step: np.ndarray) -> np.ndarray:  # type: ignore[no-untyped-def]
    cols = []
    for i in range(len(x)):
        hi, lo = x.copy(), x.copy()
        hi[i] += step[i]
        lo[i] -= step[i]
        cols.append((np.asarray(fn(hi)) - np.asarray(fn(lo))) / (2.0 * step[i]))
    return np.column_stack(cols)


STEP = np.array([1e-4, 1e-5, 1e-6, 1e-8, 1e-6, 1e-6, 1e-6, 1e-6, 1e-5, 1e-6, 1e-6, 1e-6, 1e-5])


def test_params_array_follows_the_named_indices() -> None:
    names = [f.name for f in dataclasses.fields(state.ModelParams)]
    assert len(names) == state.NP
    prm = state.ModelParams(jerk_psd=0.3, odometer_noise_mps=0.07, bias0_mps2=2e-3).array()
    assert prm[state.P_QJ] == 0.3
    assert prm[state.P_RODO] == 0.07
    assert prm[state.P_B0] == 2e-3
    assert prm[state.P_G] == G


def test_f_is_the_motion_and_the_track() -> None:
    x, dt = _x(), 0.01
    # by hand: v + a dt = 12.004, S + K v dt = 0.15 + 2e-4 * 12 * 0.01 = 0.150024
    out = process.f(x, dt, _prm())
    assert out[V] == pytest.approx(12.004, abs=1e-12)
    assert out[S] == pytest.approx(0.150024, abs=1e-12)
    unchanged = [A, K, E, B1, B2, B3, L, P, C]
    assert np.array_equal(out[unchanged], x[unchanged])


def test_f_jacobian_is_the_finite_difference() -> None:
    prm = _prm(pitch_frequency_hz=1.6, pitch_damping=0.2)
    for x in (_x(), _x(comp=1.5e-3, body=(4e-4, -2e-3)), _x(a=-1.1, comp=3e-3)):
        for dt in (0.02, 0.3):
            num = _numeric_jacobian(lambda y, dt=dt: process.f(y, dt, prm), x, STEP)
            np.testing.assert_allclose(process.jacobian(x, dt, prm), num, rtol=0, atol=1e-9)


def _body_ode(tb: float, tw: float, settle: float, wn: float, zeta: float, dt: float) -> tuple:
    """The body's pitch integrated from the physics, TB'' = wn^2 (settle - TB) - 2 zeta wn TB'
    (RK4, fine steps): the reference for process.f's closed form."""
    n = 20000
    h = dt / n

    def d(y: np.ndarray) -> np.ndarray:
        return np.array([y[1], wn * wn * (settle - y[0]) - 2.0 * zeta * wn * y[1]])

    y = np.array([tb, tw])
    for _ in range(n):
        k1 = d(y)
        k2 = d(y + 0.5 * h * k1)
        k3 = d(y + 0.5 * h * k2)
        k4 = d(y + h * k3)
        y = y + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    return float(y[0]), float(y[1])


def test_f_pitches_the_body_as_its_suspension_responds_to_c_a() -> None:
    fn, zeta = 1.2, 0.25
    prm = _prm(pitch_frequency_hz=fn, pitch_damping=zeta)
    wn = 2.0 * math.pi * fn
    comp, a = math.radians(0.05), 0.9  # the emulator's default compliance, 0.05 deg per m/s^2
    for body, dt in (((0.0, 0.0), 0.02), ((3e-4, -1e-3), 0.02), ((-2e-4, 5e-3), 0.4)):
        out = process.f(_x(a=a, comp=comp, body=body), dt, prm)
        want = _body_ode(body[0], body[1], comp * a, wn, zeta, dt)
        assert out[TB] == pytest.approx(want[0], rel=0, abs=1e-12)
        assert out[TW] == pytest.approx(want[1], rel=0, abs=1e-11)
    # a step of acceleration from rest: the first overshoot, at pi / wd, is
    # exp(-zeta pi / sqrt(1 - zeta^2)) of the settled C a (by hand 44.4 % at zeta 0.25)
    wd = wn * math.sqrt(1.0 - zeta * zeta)
    x = _x(a=a, comp=comp)
    steps = 400
    for _ in range(steps):
        x = process.f(x, math.pi / wd / steps, prm)
    overshoot = math.exp(-zeta * math.pi / math.sqrt(1 - zeta**2))
    assert x[TB] / (comp * a) - 1.0 == pytest.approx(overshoot, rel=1e-9)
    assert x[TB] / (comp * a) - 1.0 == pytest.approx(0.4443, abs=1e-4)
    # and settles at C a (nose up accelerating: 0.045 deg)
    for _ in range(300):
        x = process.f(x, 0.1, prm)
    assert x[TB] == pytest.approx(comp * a, rel=1e-9)
    assert math.degrees(x[TB]) == pytest.approx(0.045, rel=1e-9)


def test_q_of_the_jerk_is_the_integral_of_white_jerk() -> None:
    # Q_va = int_0^dt Phi(t) [0, 1]^T q [0, 1] Phi(t)^T dt, Phi = [[1, t], [0, 1]]
    q, dt = 0.3, 0.05
    t = np.linspace(0.0, dt, 20001)
    qvv = np.trapezoid(q * t * t, t)
    qva = np.trapezoid(q * t, t)
    out = process.noise(_x(v=0.0), dt, _prm(jerk_psd=q))
    assert out[V, V] == pytest.approx(qvv, rel=1e-6)
    assert out[V, A] == pytest.approx(qva, rel=1e-6)
    assert out[A, A] == pytest.approx(q * dt, rel=1e-12)


def test_q_of_the_track_grows_with_distance_only() -> None:
    prm = _prm(grade_psd_per_m=1e-8, grade_rate_psd_per_m=1e-7, wheel_scale_psd_per_m=1e-10)
    at_rest = process.noise(_x(v=0.0), 1.0, prm)
    assert at_rest[S, S] == at_rest[K, K] == at_rest[S, K] == at_rest[E, E] == 0.0
    # 20 m travelled forwards or backwards: the same variances, S-K covariance signed by dx
    ahead = process.noise(_x(v=20.0), 1.0, prm)
    back = process.noise(_x(v=-20.0), 1.0, prm)
    assert ahead[S, S] == pytest.approx(1e-8 * 20 + 1e-7 * 8000 / 3, rel=1e-12)
    assert ahead[K, K] == pytest.approx(1e-7 * 20, rel=1e-12)
    assert ahead[S, K] == pytest.approx(1e-7 * 400 / 2, rel=1e-12)
    assert back[S, K] == -ahead[S, K]
    assert ahead[E, E] == pytest.approx(1e-10 * 20, rel=1e-12)
    assert np.all(np.linalg.eigvalsh(ahead) >= -1e-18)


def test_q_of_the_biases_and_the_latency_grows_with_time() -> None:
    prm = _prm(bias_psd=1e-9, latency_psd=1e-6, load_pitch_psd=1e-8, odometer_noise_mps=0.01)
    at_rest = process.noise(_x(v=0.0), 2.0, prm)
    for b in (B1, B2, B3):
        assert at_rest[b, b] == pytest.approx(2e-9, rel=1e-12)
    assert at_rest[L, L] == pytest.approx(2e-6, rel=1e-12)
    # the load moves the body's pitch only while the train stands
    assert at_rest[P, P] == pytest.approx(2e-8, rel=1e-12)
    assert process.noise(_x(v=0.5), 2.0, prm)[P, P] == 0.0


def _channels_reference(x: np.ndarray) -> np.ndarray:
    """Plain numpy from the geometry: (u, w) rotated onto each channel's axis, plus bias."""
    u = x[A] + x[S]
    c = np.sqrt(G**2 - x[S] ** 2)
    w = c + x[V] ** 2 * x[K] / c
    th = THETA + x[P] + x[TB]  # the body pitched by P + TB turns every axis
    return np.column_stack([np.cos(th), np.sin(th)]) @ np.array([u, w]) + x[[B1, B2, B3]]


def test_channels_at_rest_on_a_gradient_read_g_sin_of_alpha_plus_theta() -> None:
    alpha = math.atan(0.015)  # 15 permil
    x = _x(v=0.0, a=0.0, s=G * math.sin(alpha), k=0.0, b=(0.0, 0.0, 0.0))
    expected = G * np.sin(alpha + THETA)
    np.testing.assert_allclose(measure.channels(x, COS, SIN, _prm()), expected, atol=1e-12)
    # the body pitched 0.02 deg nose up by its load: every axis turns with it
    x[P] = math.radians(0.02)
    expected = G * np.sin(alpha + THETA + math.radians(0.02))
    np.testing.assert_allclose(measure.channels(x, COS, SIN, _prm()), expected, atol=1e-12)
    # and by 0.01 deg more on its suspension (an acceleration's): the angles add
    x[TB] = math.radians(0.01)
    expected = G * np.sin(alpha + THETA + math.radians(0.03))
    np.testing.assert_allclose(measure.channels(x, COS, SIN, _prm()), expected, atol=1e-12)


def test_channels_match_the_reference_and_their_jacobian() -> None:
    prm = _prm()
    for x in (
        _x(),
        _x(v=-30.0, s=-0.3, k=-5e-4),
        _x(v=0.0, k=0.0),
        _x(pitch=0.004),
        _x(pitch=0.001, comp=2e-3, body=(8e-4, 3e-3)),
    ):
        np.testing.assert_allclose(
            measure.channels(x, COS, SIN, prm), _channels_reference(x), atol=1e-12
        )
        num = _numeric_jacobian(lambda y: measure.channels(y, COS, SIN, prm), x, STEP)
        np.testing.assert_allclose(
            measure.channels_jacobian(x, COS, SIN, prm), num, rtol=1e-6, atol=1e-8
        )


def test_a_vertical_curve_presses_the_car_by_v2_over_r() -> None:
    # level track, sag of radius 2000 m at 20 m/s: w = g + 400/2000 = g + 0.2
    x = _x(v=20.0, a=0.0, s=0.0, k=G / 2000.0, b=(0.0, 0.0, 0.0))
    y = measure.channels(x, np.array([0.0, 0.0, 1.0]), np.array([1.0, 1.0, 0.0]), _prm())
    assert y[0] == pytest.approx(G + 0.2, abs=1e-12)


def test_odometer_reads_the_scaled_delayed_speed_and_its_jacobian() -> None:
    x, delta = _x(v=10.0, a=0.5, e=0.01), 0.08
    # by hand: 1.01 * (10 - 0.08 * 0.5) = 10.0596
    assert measure.odometer(x, delta)[0] == pytest.approx(10.0596, abs=1e-12)
    num = _numeric_jacobian(lambda y: measure.odometer(y, delta), x, STEP)
    np.testing.assert_allclose(measure.odometer_jacobian(x, delta), num, atol=1e-8)
    # a latency of 20 ms beyond the clock mapping: 1.01 * (10 - 0.1 * 0.5) = 10.04950
    late = _x(v=10.0, a=0.5, e=0.01, lat=0.02)
    assert measure.odometer(late, delta)[0] == pytest.approx(10.0495, abs=1e-12)
    num = _numeric_jacobian(lambda y: measure.odometer(y, delta), late, STEP)
    np.testing.assert_allclose(measure.odometer_jacobian(late, delta), num, atol=1e-8)
    assert measure.odometer_jacobian(late, delta)[0, L] == pytest.approx(-1.01 * 0.5)
    assert measure.odometer_noise(_prm(odometer_noise_mps=0.04))[0, 0] == pytest.approx(0.0016)


def test_channel_noise_is_white_plus_the_body_through_each_mounting() -> None:
    prm = _prm(channel_noise_mps2=0.01, vibration_u_mps2=0.02, vibration_w_mps2=0.1)
    cos, sin = np.array([1.0, 0.0, math.sqrt(0.5)]), np.array([0.0, 1.0, math.sqrt(0.5)])
    r = measure.channels_noise(cos, sin, prm, 0.0, 0.0)
    # by hand: along-track channel 1e-4 + 4e-4, normal 1e-4 + 1e-2, the 45 deg channel
    # 1e-4 + (4e-4 + 1e-2) / 2; channels 1-2 share nothing, 1-3 share u / sqrt 2
    assert r[0, 0] == pytest.approx(5e-4)
    assert r[1, 1] == pytest.approx(1.01e-2)
    assert r[2, 2] == pytest.approx(1e-4 + 5.2e-3)
    assert r[0, 1] == pytest.approx(0.0, abs=1e-18)
    assert r[0, 2] == pytest.approx(4e-4 * math.sqrt(0.5))
    # a learnt vibration above the floors takes their place: 0.05 m/s^2 along the track
    learnt = measure.channels_noise(cos, sin, prm, 2.5e-3, 0.0)
    assert learnt[0, 0] == pytest.approx(1e-4 + 2.5e-3)
    assert learnt[1, 1] == pytest.approx(1.01e-2)


def test_cholesky_inverse_is_the_inverse() -> None:
    rng = np.random.default_rng(3)
    m = rng.normal(size=(5, 5))
    spd = m @ m.T + 5 * np.eye(5)
    np.testing.assert_allclose(linalg.spd_inverse(spd) @ spd, np.eye(5), atol=1e-12)


def test_scalar_update_is_the_textbook_one() -> None:
    # prior N(2, 4), measurement 3 with variance 1: posterior mean 2 + 4/5, variance 4/5
    x, p, nis = ekf.update(
        np.array([2.0]),
        np.array([[4.0]]),
        np.array([3.0]),
        np.array([2.0]),
        np.eye(1),
        np.eye(1),
    )
    assert x[0] == pytest.approx(2.8)
    assert p[0, 0] == pytest.approx(0.8)
    assert nis == pytest.approx(1.0 / 5.0)


def test_joseph_update_equals_the_standard_form_for_the_optimal_gain() -> None:
    rng = np.random.default_rng(5)
    m = rng.normal(size=(NX, NX))
    cov = m @ m.T + np.eye(NX)
    jac = rng.normal(size=(3, NX))
    r = np.diag([0.1, 0.2, 0.3])
    x, z, hx = rng.normal(size=NX), rng.normal(size=3), rng.normal(size=3)
    got_x, got_p, _ = ekf.update(x, cov, z, hx, jac, r)
    s = jac @ cov @ jac.T + r
    gain = cov @ jac.T @ np.linalg.inv(s)
    np.testing.assert_allclose(got_x, x + gain @ (z - hx), atol=1e-10)
    np.testing.assert_allclose(got_p, cov - gain @ s @ gain.T, atol=1e-10)


def test_one_measurement_update_equals_the_standard_form() -> None:
    # the odometer's update takes its own scalar path: the same posterior as the textbook
    rng = np.random.default_rng(8)
    m = rng.normal(size=(NX, NX))
    cov = m @ m.T + np.eye(NX)
    jac = np.zeros((1, NX))
    jac[0, [V, A, E, L]] = rng.normal(size=4)
    x, z, hx, r = rng.normal(size=NX), np.array([0.7]), np.array([0.2]), np.array([[0.05]])
    got_x, got_p, nis = ekf.update(x, cov, z, hx, jac, r)
    s = float((jac @ cov @ jac.T + r)[0, 0])
    gain = (cov @ jac.T / s)[:, 0]
    np.testing.assert_allclose(got_x, x + gain * 0.5, atol=1e-12)
    np.testing.assert_allclose(got_p, cov - s * np.outer(gain, gain), atol=1e-10)
    assert np.array_equal(got_p, got_p.T)
    assert nis == pytest.approx(0.25 / s, rel=1e-12)


def test_predict_propagates_the_covariance() -> None:
    jac = np.array([[1.0, 0.5], [0.0, 1.0]])
    cov = np.array([[1.0, 0.0], [0.0, 2.0]])
    _, p = ekf.predict(np.zeros(2), jac, cov, np.eye(2) * 0.1)
    # by hand: [[1 + 0.25 * 2 + 0.1, 0.5 * 2], [1, 2.1]]
    np.testing.assert_allclose(p, [[1.6, 1.0], [1.0, 2.1]], atol=1e-15)


def _constant_velocity(n: int, seed: int) -> tuple[np.ndarray, ...]:
    """A constant-velocity track measured in position: F, Q, H, R, prior and data."""
    dt, q, r = 0.5, 0.2, 0.3
    f = np.array([[1.0, dt], [0.0, 1.0]])
    qm = q * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
    h = np.array([[1.0, 0.0]])
    rm = np.array([[r]])
    x0, p0 = np.array([0.0, 1.0]), np.diag([4.0, 1.0])
    rng = np.random.default_rng(seed)
    truth = [rng.multivariate_normal(x0, p0)]
    for _ in range(n - 1):
        truth.append(f @ truth[-1] + rng.multivariate_normal(np.zeros(2), qm))
    z = np.array([t[0] + rng.normal(0.0, math.sqrt(r)) for t in truth])
    return f, qm, h, rm, x0, p0, z


def _dense_posterior(f, qm, h, rm, x0, p0, z):  # type: ignore[no-untyped-def]
    """The joint Gaussian posterior of all states at once: the information matrix of the
    stacked states (prior + every process step + every measurement) solved densely."""
    n, m = len(z), len(x0)
    info = np.zeros((n * m, n * m))
    vec = np.zeros(n * m)
    pi, qi, ri = np.linalg.inv(p0), np.linalg.inv(qm), np.linalg.inv(rm)
    info[:m, :m] += pi
    vec[:m] += pi @ x0
    for k in range(n):
        sl = slice(k * m, (k + 1) * m)
        info[sl, sl] += h.T @ ri @ h
        vec[sl] += h.T @ ri @ np.array([z[k]])
        if k:
            # residual x_k - F x_k-1 with weight Q^-1
            d = np.zeros((m, n * m))
            d[:, sl] = np.eye(m)
            d[:, (k - 1) * m : k * m] = -f
            info += d.T @ qi @ d
    cov = np.linalg.inv(info)
    return (cov @ vec).reshape(n, m), np.array(
        [cov[k * m : (k + 1) * m, k * m : (k + 1) * m] for k in range(n)]
    )


def test_rts_is_the_dense_least_squares_posterior_of_a_linear_model() -> None:
    f, qm, h, rm, x0, p0, z = _constant_velocity(40, seed=11)
    n = len(z)
    xp, pp, xf, pf = np.zeros((n, 2)), np.zeros((n, 2, 2)), np.zeros((n, 2)), np.zeros((n, 2, 2))
    jac = np.zeros((n, 2, 2))
    x, p = x0, p0
    for k in range(n):
        if k:
            x, p = ekf.predict(f @ x, f, p, qm)
            jac[k] = f
        xp[k], pp[k] = x, p
        x, p, _ = ekf.update(x, p, z[k : k + 1], h @ x, h, rm)
        xf[k], pf[k] = x, p
    xs, ps = smoother.rts(xp, pp, xf, pf, jac)
    want_x, want_p = _dense_posterior(f, qm, h, rm, x0, p0, z)
    np.testing.assert_allclose(xs, want_x, rtol=0, atol=1e-9)
    np.testing.assert_allclose(ps, want_p, rtol=0, atol=1e-10)
    # the last smoothed state is the filtered one; earlier ones are more certain
    assert np.array_equal(xs[-1], xf[-1])
    assert np.all(ps[:-1, 0, 0] < pf[:-1, 0, 0])


@pytest.mark.parametrize(
    "fn,args",
    [
        (process.f, (_x(comp=1e-3, body=(1e-4, 1e-3)), 0.01, _prm())),
        (process.jacobian, (_x(comp=1e-3), 0.01, _prm())),
        (process.noise, (_x(), 0.01, _prm())),
        (measure.channels, (_x(), COS, SIN, _prm())),
        (measure.channels_jacobian, (_x(), COS, SIN, _prm())),
        (measure.odometer_jacobian, (_x(), 0.05)),
    ],
)
def test_compiled_and_plain_python_agree(fn, args) -> None:  # type: ignore[no-untyped-def]
    py = getattr(fn, "py_func", fn)  # NUMBA_DISABLE_JIT=1: there is no compiled twin
    np.testing.assert_allclose(fn(*args), py(*args), rtol=1e-14, atol=1e-18)


def test_products_are_numpy_s() -> None:
    rng = np.random.default_rng(7)
    a, b, x = rng.normal(size=(3, 5)), rng.normal(size=(5, 4)), rng.normal(size=5)
    np.testing.assert_allclose(linalg.mm(a, b), a @ b, atol=1e-13)
    np.testing.assert_allclose(linalg.mv(a, x), a @ x, atol=1e-13)
    p = np.eye(5) + 0.1
    np.testing.assert_allclose(linalg.sandwich(a, p), a @ p @ a.T, atol=1e-13)
    np.testing.assert_allclose(linalg.sandwich_dense(a, p), a @ p @ a.T, atol=1e-13)


def test_spd_solve_is_the_inverse_times_b() -> None:
    rng = np.random.default_rng(4)
    m = rng.normal(size=(6, 6))
    spd = m @ m.T + 6 * np.eye(6)
    b = rng.normal(size=(6, 4))
    np.testing.assert_allclose(spd @ linalg.spd_solve(spd, b), b, atol=1e-12)
    np.testing.assert_allclose(linalg.cholesky(spd) @ linalg.cholesky(spd).T, spd, atol=1e-12)
    # a state known exactly (zero row and column): solved on the others, 0 in its row
    known = spd.copy()
    known[2, :] = known[:, 2] = 0.0
    b[2] = 0.0
    rest = [0, 1, 3, 4, 5]
    want = np.zeros_like(b)
    want[rest] = np.linalg.solve(known[np.ix_(rest, rest)], b[rest])
    np.testing.assert_allclose(linalg.spd_solve(known, b), want, atol=1e-12)


# ---- the vertical-curve jump test (bench.fusion.model.jump)
def test_the_jump_test_off_is_the_model_without_it() -> None:
    """curve_rate_step_per_m = 0 keeps no hypothesis and corrects nothing."""
    prm = state.ModelParams(curve_rate_step_per_m=0.0)
    glr = jump.hypotheses(prm, 0.02)
    assert glr.shape == (100, jump.WIDTH)
    x, p = state.initial(prm)
    jump.propagate(glr, np.eye(state.NX), 1.0, 0.0, prm.array())
    assert np.all(glr[:, jump.AGE] == -1.0)
    x2, p2, added, step, age = jump.test(glr, x, p, 1.0, prm.array())
    assert step == 0.0 and age == -1.0 and not added.any()
    assert np.array_equal(x2, x) and np.array_equal(p2, p)
    assert math.isfinite(float(p2.sum()))


def test_the_correction_is_the_filter_that_knew_the_step_on_a_linear_model() -> None:
    """On a linear model the corrected (x, P) is exactly the Kalman filter whose prior had
    the step's N(0, s^2) on K added at the onset (the reference: a plain filter run twice)."""
    rng = np.random.default_rng(3)
    prm_obj = state.ModelParams(curve_min_age_s=0.0, curve_spacing_m=1.0)
    prm = prm_obj.array()
    x_lin = np.zeros(state.NX)
    x_lin[state.V], x_lin[state.A], x_lin[state.S] = 15.0, 0.3, 0.1
    phi = np.eye(state.NX)
    phi[state.V, state.A] = 0.02
    phi[state.S, state.K] = 15.0 * 0.02
    q = np.diag(np.full(state.NX, 1e-10))
    th = np.radians([30.0, 0.0, -30.0])
    h = measure.channels_jacobian(x_lin, np.cos(th), np.sin(th), prm)
    r = np.eye(3) * 1e-4
    x0, p0 = state.initial(prm_obj, 15.0, 0.1)
    truth = x0.copy()
    onset, n = 20, 60
    zs = []
    for k in range(n):
        truth = phi @ truth
        if k == onset:
            truth[state.K] += 2e-3
        zs.append(h @ truth + rng.normal(0.0, 1e-2, 3))

    def run(with_prior: bool, glr: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        x, p = x0.copy(), p0.copy()
        for k in range(n):
            if glr is not None:
                jump.propagate(glr, phi, 1.0 if k == onset else 0.0, float(k), prm)
            x, p = phi @ x, phi @ p @ phi.T + q
            if with_prior and k == onset:
                p[state.K, state.K] += prm_obj.curve_rate_step_per_m**2
            x, p, _, gain, s_inv, nu = ekf.update_full(x, p, zs[k], h @ x, h, r)
            if glr is not None:
                jump.follow(glr, h, gain, s_inv, nu)
        return x, p

    glr = jump.hypotheses(prm_obj, 0.02)[:1]  # one hypothesis: the onset's
    x_a, p_a = run(False, glr)
    assert glr[0, jump.AGE] == n - 1 - onset
    x_c, p_c, _, step, age = jump.test(glr, x_a, p_a, float(n), prm)
    x_b, p_b = run(True, None)
    assert age == n - 1 - onset and step == pytest.approx(2e-3, rel=0.2)
    np.testing.assert_allclose(x_c, x_b, rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(p_c, p_b, rtol=1e-6, atol=1e-15)
