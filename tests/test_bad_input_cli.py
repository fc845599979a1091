"""The bad-input suite of the command line (issue 53): options out of range or in conflict,
damaged or mismatched files, unwritable outputs and signals. Every case exits with its documented
code (cli.EXIT_CODES) and one line naming the file or option and the fix, never a traceback or
"internal error", and leaves the previous files and the .blend byte-identical.

One tiny scene is baked once per module (a floor and a box, two lamps in Light Groups, 256²,
4 samples); each case works on a copy of that folder. Options are checked by the parser alone;
files through the in-process command line (`cli_run`); signals in processes of their own.
"""

import hashlib
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from hhd_lightmapper import cli
from hhd_lightmapper.cli import option_types, options
from hhd_lightmapper.core.console import interrupt_as_cancel, terminate_as_interrupt
from hhd_lightmapper.core.errors import BakeError
from hhd_lightmapper.core.files import exr, lightmap_files
from scenekit import blender as kit

pytestmark = pytest.mark.bpy
OBJECTS = ("--objects", "Floor", "Box")


@pytest.fixture(scope="module")
def baked(extension, tmp_path_factory) -> Path:
    """A folder holding scene.blend and lightmaps/ (its bake: light sets Red and Blue, seams)."""
    import bpy

    folder = tmp_path_factory.mktemp("baked")
    scene, _ = kit.two_lamp_room()
    s = scene.hhd
    s.preset = 'CUSTOM'
    s.samples, s.bounces, s.denoise, s.stitch_seams, s.pack_images = 4, 0, False, True, False
    s.output_dir = "//lightmaps"
    bpy.ops.wm.save_as_mainfile(filepath=str(folder / "scene.blend"))
    assert cli.main(["bake", *OBJECTS]) == cli.EXIT_OK
    assert (folder / "lightmaps" / "Lightmap.Red_hhd.exr").is_file()
    return folder


def test_no_file_of_a_bake_holds_nan_or_infinity(baked):
    """Every EXR channel and JSON file the bake wrote is finite (strict JSON); the texels file's
    unknown noise (4 samples: one pass, too few to measure) is -1 there and NaN once read."""
    folder = baked / "lightmaps"
    for path in sorted(folder.glob("*.exr")):
        for name, data in exr.read(path)[0].items():
            assert np.isfinite(data).all(), (path.name, name)
    for path in sorted(folder.glob("*.json")):
        constants = []
        json.loads(path.read_text(), parse_constant=constants.append)
        assert constants == [], (path.name, constants)
    noise = exr.read(folder / "Lightmap_texels.exr")[0]["Noise.V"]
    assert (noise == -1.0).all()
    assert np.isnan(lightmap_files.read_texel_data(lightmap_files.AtlasFiles(folder, "Lightmap")).noise).all()


@pytest.fixture
def work(baked, tmp_path) -> Path:
    """A copy of the baked folder for one case."""
    shutil.copytree(baked, tmp_path / "work")
    return tmp_path / "work"


def hashes(folder: Path) -> dict[str, str]:
    """SHA-256 of every file under `folder` (the .blend and the lightmaps, temporaries included)."""
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def assert_plain(result, code: int, *words: str) -> None:
    """Exit `code`, and an error line holding every one of `words`: no traceback, no internal error."""
    assert result.returncode == code, (result.returncode, result.stderr)
    err = result.stderr
    assert "Traceback" not in err and "internal error" not in err, err
    for word in words:
        assert word in err, (word, err)


# --- options: the parser alone --------------------------------------------------------------------


@pytest.mark.parametrize(
    "args, words",
    [
        (["--samples", "0"], ["--samples", "4–65536"]),
        (["--samples", "1"], ["--samples", "4–65536"]),
        (["--samples", "-3"], ["--samples", "4–65536"]),
        (["--samples", "many"], ["invalid int value", "4–65536"]),
        (["--bounces", "100"], ["--bounces", "0–16"]),
        (["--resolution", "64"], ["--resolution", "256–8192"]),
        (["--resolution", "100000"], ["--resolution", "256–8192"]),
        (["--noise-target", "-1"], ["--noise-target", "0–50"]),
        (["--noise-target", "nan"], ["--noise-target", "not a finite number"]),
        (["--time-budget", "-5"], ["--time-budget", "≥ 0 s"]),
        (["--time-budget", "nan"], ["--time-budget", "not a finite number"]),
        (["--time-budget", "inf"], ["--time-budget", "not a finite number"]),
        (["--texel-density", "-1"], ["--texel-density", "≥ 0"]),
        (["--texel-density", "inf"], ["--texel-density", "not a finite number"]),
        (["--seed", "-1"], ["--seed", f"0–{option_types.INT_MAX}"]),
        (["--seed", "99999999999"], ["--seed", f"0–{option_types.INT_MAX}"]),
        (["--threads", "100000"], ["--threads", f"≤ {option_types.MAX_THREADS}"]),
        (["--scheduler", "farm-head"], ["--scheduler", "tcp://HOST:PORT"]),
        (["--scheduler", "tcp://[::1"], ["--scheduler", "brackets"]),
        (["--scheduler", "http://farm:8786"], ["--scheduler", "unknown protocol"]),
        (["--scheduler", "tcp://farm:99999"], ["--scheduler", "1–65535"]),
        (["--texel-density", "10", "--resolution", "512"], ["--texel-density", "--resolution", "give one"]),
        (["--objects", "Floor", "--collection", "Level"], ["--objects", "--collection", "give one"]),
    ],
    ids=lambda v: " ".join(v) if isinstance(v, list) and v and v[0].startswith("--") else "",
)
def test_bake_options_out_of_range_or_in_conflict_exit_2_with_the_range(args, words, capsys):
    assert cli.main(["bake", *args]) == cli.EXIT_USAGE
    err = capsys.readouterr().err
    assert "Traceback" not in err
    for word in words:
        assert word in err, (word, err)


@pytest.mark.parametrize(
    "args, words",
    [
        (["blend", "--weights", "Red=1e300"], ["'Red'", "0–1000"]),
        (["blend", "--weights", "Red=-1"], ["'Red'", "0–1000"]),
        (["blend", "--weights", "Red=1,nan,1"], ["'Red'", "0–1000"]),
        (["unwrap", "--texel-density", "5", "--resolution", "512"], ["give one"]),
        (["encode", "--objects", "Floor", "--collection", "Level"], ["give one"]),
        (["encode", "--threads", "5000"], ["--threads", "≤ 1024"]),
    ],
)
def test_other_commands_options_exit_2(args, words, capsys):
    assert cli.main(args) == cli.EXIT_USAGE
    err = capsys.readouterr().err
    for word in words:
        assert word in err, (word, err)


def test_help_and_a_valid_value_still_parse(capsys):
    args = options.parse(
        options.parser(), ["bake", "--samples", "4", "--time-budget", "0", "--seed", str(option_types.INT_MAX)]
    )
    assert args.samples == 4 and args.time_budget == 0.0 and args.seed == option_types.INT_MAX
    args = options.parse(options.parser(), ["unwrap", "--texel-density", "0", "--resolution", "512"])  # 0: no density
    assert args.resolution == 512
    assert cli.main(["bake", "--texel-density", "500", "--help"]) == cli.EXIT_OK
    capsys.readouterr()


# --- files: damaged, mismatched, unwritable ------------------------------------------------------


def damage(path: Path, how: str) -> None:
    data = bytearray(path.read_bytes())
    if how == "truncate":
        path.write_bytes(bytes(data[: len(data) // 2]))
    else:  # flip bits through the pixel data
        for i in range(400, len(data), 97):
            data[i] ^= 0x5A
        path.write_bytes(bytes(data))


def shrink(path: Path) -> None:
    """Replace an EXR by one of half the size (the same channels): a file of another bake."""
    channels, _ = exr.read(path)
    halves = {n: np.ascontiguousarray(a[::2, ::2]) for n, a in channels.items()}
    exr.write(path, halves)


@pytest.mark.parametrize(
    "command, file, how, words",
    [
        ("encode", "Lightmap_sh.exr", "truncate", ["Lightmap_sh.exr", "damaged", "bake again"]),
        ("blend", "Lightmap_sh.exr", "truncate", ["Lightmap_sh.exr", "damaged", "bake again"]),
        ("encode", "Lightmap_texels.exr", "flip", ["Lightmap_texels.exr", "damaged", "bake again"]),
        ("blend", "Lightmap.Red_hhd.exr", "flip", ["Lightmap.Red_hhd.exr", "damaged", "bake again"]),
        ("encode", "Lightmap.json", "[1, 2]", ["Lightmap.json", "not an object", "bake again"]),
        ("blend", "Lightmap.json", '"text"', ["Lightmap.json", "not an object", "bake again"]),
        ("encode", "Lightmap.json", "{", ["Lightmap.json", "invalid JSON", "bake again"]),
        ("encode", "Lightmap_seams.npz", "garbage", ["Lightmap_seams.npz", "damaged", "--no-stitch"]),
        ("encode", "Lightmap_texels.exr", "shrink", ["Lightmap_texels.exr", "different bakes", "128×128"]),
        ("blend", "Lightmap.Blue_hhd.exr", "shrink", ["Lightmap.Blue_hhd.exr", "different bakes"]),
    ],
)
def test_a_damaged_or_mismatched_file_exits_1_naming_it(work, cli_run, command, file, how, words):
    path = work / "lightmaps" / file
    if how in ("truncate", "flip"):
        damage(path, how)
    elif how == "shrink":
        shrink(path)
    elif how == "garbage":
        path.write_bytes(b"not a seams file" * 8)
    else:
        path.write_text(how)
    before = hashes(work)
    result = cli_run(work / "scene.blend", command, *OBJECTS)
    assert_plain(result, cli.EXIT_INPUT, *words)
    assert "allow_pickle" not in result.stderr
    if "seams" not in file:
        assert "seams" not in result.stderr  # the seams file is not blamed for another file
    assert hashes(work) == before


def test_the_reencode_operator_reports_a_damaged_file_in_one_line(work):
    import bpy

    damage(work / "lightmaps" / "Lightmap_sh.exr", "truncate")
    before = hashes(work)
    bpy.ops.wm.open_mainfile(filepath=str(work / "scene.blend"))
    with pytest.raises(RuntimeError, match=r"Re-encode failed: cannot read .*Lightmap_sh\.exr: the file is damaged"):
        bpy.ops.hhd.encode()
    assert hashes(work) == before


def test_out_pointing_at_a_file_exits_4_before_baking(work, cli_run):
    (work / "a_file").write_text("not a folder")
    before = hashes(work)
    result = cli_run(work / "scene.blend", "bake", *OBJECTS, "--out", work / "a_file")
    assert_plain(result, cli.EXIT_OUTPUT, str(work / "a_file"), "is a file, not a folder", "give --out a folder")
    assert "Errno" not in result.stderr and "bake:" not in result.stdout  # refused before any work
    below = cli_run(work / "scene.blend", "bake", *OBJECTS, "--out", work / "a_file" / "sub")
    assert_plain(below, cli.EXIT_OUTPUT, "is a file, so the folder", "give --out a folder")
    assert hashes(work) == before


def test_save_to_a_read_only_blend_exits_4_before_baking(work, cli_run, monkeypatch):
    blend = work / "scene.blend"
    blend.chmod(0o444)
    if os.geteuid() == 0:  # root may write anything: make os.access honour the mode bits, as for a user
        real = os.access
        monkeypatch.setattr(
            os, "access", lambda p, m: real(p, m) and not (m & os.W_OK and not os.stat(p).st_mode & 0o222)
        )
    before = hashes(work)
    result = cli_run(blend, "bake", *OBJECTS, "--save")
    assert_plain(result, cli.EXIT_OUTPUT, str(blend), "read-only", "leave out --save")
    assert "bake:" not in result.stdout  # nothing was baked
    assert hashes(work) == before
    blend.chmod(0o644)


def test_an_extreme_texel_density_is_refused_before_xatlas(work, cli_run):
    before = hashes(work)
    start = time.perf_counter()
    result = cli_run(work / "scene.blend", "unwrap", *OBJECTS, "--texel-density", "1e6")
    assert_plain(result, cli.EXIT_INPUT, "1e+06 per metre", "use at most", "'")
    assert "xatlas" not in result.stdout and time.perf_counter() - start < 10.0
    assert hashes(work) == before


def test_the_scenes_malformed_scheduler_setting_exits_1(work, cli_run):
    import bpy

    bpy.ops.wm.open_mainfile(filepath=str(work / "scene.blend"))
    bpy.context.scene.hhd.scheduler = "farm-head"
    bpy.ops.wm.save_mainfile()
    before = hashes(work)
    result = cli_run(work / "scene.blend", "bake", *OBJECTS)
    assert_plain(result, cli.EXIT_INPUT, "Dask Scheduler setting 'farm-head'", "tcp://HOST:PORT")
    assert hashes(work) == before


def test_writers_refuse_non_finite_values_naming_the_file_and_channel(tmp_path):
    target = tmp_path / "Lightmap_hhd.exr"
    exr.write(target, {"Iz.R": np.ones((80, 4), np.float32)})
    before = target.read_bytes()
    bad = np.ones((80, 4), np.float32)
    bad[70, 1] = np.inf  # in the second band of rows: after the first was written
    with pytest.raises(exr.NonFiniteValue, match=r"Lightmap_hhd\.exr: channel 'Iz\.R' holds NaN or infinity"):
        exr.write(target, {"Iz.R": bad})
    with exr.Staging() as staging:  # no channel is let through: the noise layer's "unknown" is -1
        for value in (np.nan, np.inf):
            with pytest.raises(exr.NonFiniteValue, match="'Noise.V'"):
                exr.write_file(staging.stage(tmp_path / "u.exr"), {"Noise.V": np.full((4, 4), value, np.float32)})
        with pytest.raises(exr.NonFiniteValue, match=r"Lightmap\.json: bake\.time_budget is NaN"):
            staging.write_json(tmp_path / "Lightmap.json", {"bake": {"samples": 4, "time_budget": math.nan}})
    assert target.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["Lightmap_hhd.exr"]  # no temporaries, no json
    assert issubclass(exr.NonFiniteValue, BakeError)


# --- signals and temporary files -----------------------------------------------------------------


def test_sigterm_cancels_like_ctrl_c_and_staged_files_are_deleted(tmp_path):
    with interrupt_as_cancel() as cancel:  # in a bake: the first SIGTERM asks to stop
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0.01)
        assert cancel()
    with pytest.raises(KeyboardInterrupt), terminate_as_interrupt(), exr.Staging() as staging:
        exr.write_file(staging.stage(tmp_path / "a.exr"), {"V.V": np.zeros((4, 4), np.float32)})
        os.kill(os.getpid(), signal.SIGTERM)  # while writing: raised here, the staging discarded
        time.sleep(1.0)
    assert list(tmp_path.iterdir()) == []
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL


def dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_a_bake_removes_stale_temporaries_of_dead_processes_only(work, cli_run):
    folder = work / "lightmaps"
    host = exr._host()
    dead, live = dead_pid(), os.getpid()
    stale = [
        folder / f".Lightmap_hhd.exr.{host}-{dead}.0123abcd.tmp",
        folder / f".Lightmap.json.{dead}.89abcdef.tmp",  # named before the host was recorded
    ]
    kept = [
        folder / f".Lightmap_sh.exr.{host}-{live}.0123abcd.tmp",  # a live process's
        folder / f".Lightmap_sh.exr.other-machine-{dead}.0123abcd.tmp",  # another host's (a shared folder)
    ]
    for path in stale + kept:
        path.write_bytes(b"partial")
    result = cli_run(work / "scene.blend", "bake", *OBJECTS)
    assert result.returncode == cli.EXIT_OK, result.stderr
    assert not any(p.exists() for p in stale) and all(p.exists() for p in kept)
    assert exr.target_of(kept[0]) == folder / "Lightmap_sh.exr"


def run_process(blend: Path, *args) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "hhd_lightmapper.cli", str(blend), *map(str, args)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


@pytest.mark.parametrize(
    "stage, samples, line",
    [
        ("tracing", 1024, r"%\] bake points"),  # the first progress line: tracing starts next
        ("writing", 4, None),  # once the first file is staged: post stages done, the writes under way
    ],
    ids=["tracing", "writing"],
)
def test_sigterm_during_a_bake_exits_5_and_leaves_nothing_behind(work, stage, samples, line):
    import re

    before = hashes(work)
    proc = run_process(work / "scene.blend", "bake", *OBJECTS, "--samples", samples)
    if stage == "writing":  # the first file staged (its temporary), whatever the console says
        deadline = time.monotonic() + 120.0
        while not list(work.rglob("*.tmp")) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.002)
        assert proc.poll() is None, "the bake ended before a file was staged"
        proc.send_signal(signal.SIGTERM)
    else:
        for text in proc.stdout:
            if re.search(line, text):
                proc.send_signal(signal.SIGTERM)
                break
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == cli.EXIT_CANCELLED, err
    assert "interrupted: no output file was replaced" in err and "Traceback" not in err
    assert not list(work.rglob("*.tmp"))
    assert hashes(work) == before


def test_an_interrupt_while_starting_exits_5_without_a_traceback(work):
    before = hashes(work)
    proc = run_process(work / "scene.blend", "bake", *OBJECTS)
    time.sleep(0.3)  # importing bpy and numpy
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == cli.EXIT_CANCELLED, err
    assert "Traceback" not in err and "ImportError" not in err and "interrupted" in err
    assert hashes(work) == before
