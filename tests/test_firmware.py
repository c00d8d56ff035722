"""The controller on a Cortex-M7: the firmware of ``export-c --target cortex-m7`` (the NMPC's own step) builds for
QEMU's mps2-an500 board, replays the recorded run there with the host build's commands (to 1e-9, every event and
mode the same) and reports its instructions and memory; a command changed on the way fails the check."""

import shutil
import struct
import subprocess

import pytest

from rollbot_oc.app.cli import EXIT_USAGE, main
from rollbot_oc.export.firmware import FIRMWARE_FILES, missing_tools, parse_check, qemu_check, remove_firmware, \
    write_firmware
from rollbot_oc.export.project import LOG_NAME

PERIODS = 170  # the first 1.7 s: 15 solve instants, a plan taking over at 1.56 s


def _needs_tools():
    missing = missing_tools()
    if missing:
        pytest.skip(f"no {', '.join(missing)}: the firmware cannot be built or run here (Debian: apt-get install "
                    "gcc-arm-none-eabi libnewlib-arm-none-eabi qemu-system-arm)")


@pytest.mark.slow
def test_the_firmware_replays_the_recorded_run_on_qemu(c_export, tmp_path):
    _needs_tools()
    problem, result, built = c_export
    assert built is not None and built[0] == 0, built
    folder = result.folder
    done = qemu_check(folder, PERIODS)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert "warning" not in done.stderr.lower()
    found = parse_check(done.stdout)
    assert found["passed"] and found["periods"] == PERIODS
    assert found["diff"] <= 1e-9 and found["statuses_differ"] == 0
    assert found["diff_python"] <= 1e-9  # and the Python NMPC's step's recorded commands
    assert found["solves"] == sum(p.window is not None for p in result.log[:PERIODS]) > 10
    edited = [p.k for p in result.log[:PERIODS] if len(p.after)]
    assert edited  # the host's edits of the memory replayed too (a plan taking over)
    median, p95, top = found["per_solve"]
    assert 0 < median <= p95 <= top
    assert found["per_period"][0] < median  # a period between solves costs less than a solve
    assert found["per_interval"][0] > median  # an interval: its solve and the periods after it
    assert found["ram_context"] >= result.sizes["work_bytes"] // 2  # the work arrays, with 4-byte pointers and ints
    assert found["ram"] >= found["ram_context"] + found["stack"] > found["ram_context"]
    assert 0 < found["flash_code"] < found["flash"] <= found["image_flash"]
    assert "heap: the step's objects call no allocator" in done.stdout

    # a firmware command changed by 1e-6 rad/s^2 fails the comparison
    out = (folder / "firmware_commands.bin").read_bytes()
    row = 32 + 48 * (PERIODS // 2)
    accel = struct.unpack_from("<d", out, row)[0] + 1e-6
    changed = tmp_path / "changed_commands.bin"
    changed.write_bytes(out[:row] + struct.pack("<d", accel) + out[row + 8:])
    check = subprocess.run(["python3", "firmware_check.py", "--map", "app.map", LOG_NAME, str(changed),
                            "host_commands.bin"], cwd=folder, capture_output=True, text=True)
    assert check.returncode == 1 and "qemu-check FAILED" in check.stdout
    assert 9e-7 < parse_check(check.stdout)["diff"] < 1.1e-6


def test_the_firmware_files_are_written_and_removed_whole(tmp_path):
    write_firmware(tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(FIRMWARE_FILES)
    (tmp_path / "main.c").write_text("")
    remove_firmware(tmp_path)  # what a host export over a Cortex-M7 one does
    assert [p.name for p in tmp_path.iterdir()] == ["main.c"]


def test_export_c_refuses_an_unknown_target(tmp_path, capsys):
    assert main(["export-c", "--out", str(tmp_path / "c"), "--target", "cortex-m4"]) == EXIT_USAGE
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "host" in err[0] and "cortex-m7" in err[0] and "Traceback" not in err[0]
    assert not (tmp_path / "c").exists()


def test_qemu_check_says_what_is_missing(tmp_path, monkeypatch):
    from rollbot_oc.core.errors import ConfigError

    monkeypatch.setattr(shutil, "which", lambda tool: None if tool == "qemu-system-arm" else "/usr/bin/" + tool)
    with pytest.raises(ConfigError, match="needs qemu-system-arm .*apt-get install"):
        qemu_check(tmp_path)
