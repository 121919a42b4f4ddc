"""The operator's defaults (issue 28): bench.toml in the working folder and the user's
config.toml (XDG_CONFIG_HOME honoured) give interface, channel, bitrate, config and logs;
command line > BENCH_* > ./bench.toml > user config > python-can's own config > built-in;
`bench --print-config` says where each value came from; a bad key is one line, exit 2.
Shell completion: the bash script loads in bash and completes a subcommand."""

from __future__ import annotations

import re
import shutil
import subprocess
import uuid
from pathlib import Path

import pytest

from bench.cli import main


@pytest.fixture
def home(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A clean working folder, HOME and XDG_CONFIG_HOME, no BENCH_* or CAN_* settings."""
    import os

    for name in list(os.environ):
        if name.startswith(("BENCH_", "CAN_")) and name != "BENCH_LIVE_CPU":
            monkeypatch.delenv(name)
    work, user = tmp_path / "work", tmp_path / "home"
    work.mkdir()
    user.mkdir()
    monkeypatch.chdir(work)
    monkeypatch.setenv("HOME", str(user))
    monkeypatch.setenv("XDG_CONFIG_HOME", str(user / "xdg"))
    return tmp_path


def write_user(home: Path, text: str) -> Path:
    path = home / "home" / "xdg" / "bench" / "config.toml"
    path.parent.mkdir(parents=True)
    path.write_text(text)
    return path


def printed(capsys: pytest.CaptureFixture[str], *argv: str) -> dict[str, tuple[str, str]]:
    assert main(["--print-config", *argv]) == 0
    rows = {}
    for line in capsys.readouterr().out.splitlines():
        m = re.fullmatch(r"(\w+) +(\S+) +(.+)", line)
        if m and m[1] in ("interface", "channel", "bitrate", "config", "logs"):
            rows[m[1]] = (m[2], m[3])
    return rows


def test_each_layer_wins_over_the_ones_below(
    home: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    (home / "home" / ".canrc").write_text(
        "[default]\ninterface = kvaser\nchannel = 7\nbitrate = 250000\n"
    )
    write_user(home, 'interface = "pcan"\nchannel = "PCAN_USBBUS1"\nconfig = "cal/user.toml"\n')
    (home / "work" / "bench.toml").write_text('interface = "socketcan"\nchannel = "can0"\n')
    monkeypatch.setenv("BENCH_CHANNEL", "can1")
    rows = printed(capsys, "run", "-c", "can2")
    assert rows["interface"] == ("socketcan", "./bench.toml")
    assert rows["channel"] == ("can2", "command line")
    assert rows["bitrate"][0] == "250000" and rows["bitrate"][1].startswith("python-can config")
    user_cal = home / "home" / "xdg" / "bench" / "cal" / "user.toml"  # relative to its file
    assert rows["config"] == (str(user_cal), "~/xdg/bench/config.toml")
    assert rows["logs"] == ("logs", "built-in")
    rows = printed(capsys, "run")
    assert rows["channel"] == ("can1", "BENCH_CHANNEL")
    monkeypatch.delenv("BENCH_CHANNEL")
    assert printed(capsys, "run")["channel"] == ("can0", "./bench.toml")
    (home / "work" / "bench.toml").unlink()
    assert printed(capsys)["channel"] == ("PCAN_USBBUS1", "~/xdg/bench/config.toml")


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (
            'interfce = "socketcan"\n',
            "./bench.toml: unknown key 'interfce' (the defaults file knows",
        ),
        ("bitrate = 0\n", "./bench.toml: bitrate: expected a positive integer, got 0"),
        ('interface = "socketcn"\n', "did you mean socketcan?"),
        ("logs = [1]\n", "./bench.toml: logs: expected a non-empty string, got array"),
        ("interface = \n", "./bench.toml"),  # not TOML at all
    ],
)
def test_a_bad_defaults_file_is_one_line_exit_2_whatever_the_command(
    home: Path, capsys: pytest.CaptureFixture[str], text: str, message: str
) -> None:
    (home / "work" / "bench.toml").write_text(text)
    for argv in (["--print-config"], ["log", "info", "x.mcap"], ["run", "--emulate", "demo"]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.startswith("bench: error: ") and message in err and err.count("\n") == 1


def test_a_bad_environment_value_is_one_line(
    home: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv("BENCH_BITRATE", "fast")
    assert main(["--print-config"]) == 2
    assert "BENCH_BITRATE: bitrate: expected a positive integer, got 'fast'" in (
        capsys.readouterr().err
    )


def test_bench_run_takes_its_bus_from_bench_toml(
    home: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    channel = f"from-toml-{uuid.uuid4().hex[:6]}"
    (home / "work" / "bench.toml").write_text(f'interface = "virtual"\nchannel = "{channel}"\n')
    code = main(["run", "--duration", "0.3", "--no-log", "-q"])
    assert code == 1  # nothing sends on that virtual channel: the run says so
    assert f"on can bus interface=virtual channel={channel}" in capsys.readouterr().err


def test_another_source_on_the_command_line_leaves_the_bus_defaults_out(
    home: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (home / "work" / "bench.toml").write_text(
        'interface = "virtual"\nchannel = "x"\nlogs = "runs"\n'
    )
    assert main(["run", "--emulate", "demo", "--duration", "0.3", "-q"]) == 0
    # ... while the log folder still comes from bench.toml
    assert len(list((home / "work" / "runs").glob("*-emu-demo.mcap"))) == 1


def test_the_default_sheet_stands_in_for_nominal_values_only(
    home: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    work = home / "work"
    sc = work / "short.toml"
    sc.write_text(
        "duration_s = 2.0\nsample_rate_hz = 100\n[[track]]\nlength_m = 50.0\n"
        "[[channels]]\nangle_deg = 30.4\n[[channels]]\nangle_deg = 0.3\n"
        "[[channels]]\nangle_deg = -29.6\n"
    )
    assert main(["emulate", str(sc), "--out", "run.log", "--calibration-out", "cal.toml"]) == 0
    assert main(["emulate", str(sc), "--out", "run.mcap", "-q"]) == 0
    (work / "bench.toml").write_text('config = "cal.toml"\n')
    capsys.readouterr()
    assert main(["replay", "run.log"]) == 0  # a log without a calibration: the sheet
    err = capsys.readouterr().err
    assert f"calibration: file {work / 'cal.toml'} (ch1 30.4 deg, ch2 0.3 deg" in err
    assert main(["replay", "run.mcap"]) == 0  # an MCAP keeps the one it recorded
    assert "calibration: recorded in" in capsys.readouterr().err


def test_bash_completion_loads_and_completes_a_subcommand(tmp_path: Path) -> None:
    bash = shutil.which("bash")
    if bash is None:
        pytest.skip("no bash on this machine")
    script = tmp_path / "bench.bash"
    import contextlib
    import io

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main(["--completion", "bash"]) == 0
    script.write_text(out.getvalue())

    def complete(line: str) -> list[str]:
        words = line.split(" ")
        probe = (
            f"source {script} || exit 9\n"
            f"COMP_WORDS=({line}); COMP_CWORD={len(words) - 1}\n"
            f'COMP_LINE="{line}"; COMP_POINT={len(line)}\n'
            "complete -p bench >/dev/null || exit 8\n"
            "_shtab_bench; printf '%s\\n' \"${COMPREPLY[@]}\"\n"
        )
        run = subprocess.run([bash, "-c", probe], capture_output=True, text=True, timeout=60)
        assert run.returncode == 0, run.stderr
        return run.stdout.split()

    assert complete("bench pl") == ["play"]
    assert set(complete("bench ")) >= {"run", "tui", "play", "accept", "replay", "fleet"}
    assert "--skip-to" in complete("bench play --sk")
    assert complete("bench run -i socketc") == ["socketcan", "socketcand"]


def test_zsh_completion_is_a_compdef_script(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--completion", "zsh"]) == 0
    text = capsys.readouterr().out
    assert text.startswith("#compdef bench") and "play" in text
