"""Every consumer judges a hostile or damaged file alike, by one code path, and refuses it before paying for it
(spec 2.1 §1 "Limits", §8; issue 31): `voxfmt validate` and `voxfmt inspect`, the Python package's validate()
and load(), and the MuJoCo plugin. Each class of harm is one small file (hostile_files.py) whose refusal must
name one of its codes, in well under a second and a few hundred MB whatever the file declares; Python never
raises anything but a voxfmt.Error for a bad file, and never raises from validate().

Run: VOXFMT_BIN=build/bin/voxfmt PYTHONPATH=build/python .venv/bin/python -m pytest tests/reads
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

import voxfmt
from hostile_files import Case, string_flips, write_cases

HERE = Path(__file__).resolve().parent
REPO = Path(os.environ.get("VOXFMT_REPO", HERE.parents[1]))
VOXFMT = os.environ.get("VOXFMT_BIN", str(REPO / "build/bin/voxfmt"))
sys.path.insert(0, str(REPO / "tests" / "spec"))
import spec_fixture as sf  # noqa: E402

# A refusal from the metadata costs the fork of the isolated reader and the HDF5 open: far below these, whatever
# the file declares (the files declare up to 15 GB). Not a speed target: a bound that a paid bomb would break.
MAX_RSS_MB = 300
MAX_SECONDS = 20


@pytest.fixture(scope="module")
def cases(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Case]:
    return write_cases(tmp_path_factory.mktemp("hostile"))


@pytest.fixture(scope="module")
def good(tmp_path_factory: pytest.TempPathFactory) -> str:
    return sf.write_fixture_h5py(str(tmp_path_factory.mktemp("good") / "good.vox.h5"))


def run_with_rusage(args: list[str]) -> tuple[int, str, str, float, float]:
    """(exit status, stdout, stderr, peak RSS in MB, seconds) of a command, reaped with wait4: the peak is the
    largest of the process and its isolated reader's."""
    start = time.monotonic()
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    out = proc.stdout.read()  # type: ignore[union-attr]
    err = proc.stderr.read()  # type: ignore[union-attr]
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    return proc.returncode, out, err, usage.ru_maxrss / 1024, time.monotonic() - start


def test_the_cases_are_small_files(cases: dict[str, Case]) -> None:
    for name, case in cases.items():
        assert os.path.getsize(case.path) < 8 << 20, (name, os.path.getsize(case.path))


def test_voxfmt_validate_refuses_each_before_paying(cases: dict[str, Case]) -> None:
    for name, case in cases.items():
        code, out, err, rss, seconds = run_with_rusage([VOXFMT, "validate", case.path, "--json"])
        assert code == case.exit, (name, code, out, err)
        issues = json.loads(out)["files"][0]["issues"]
        errors = [i["code"] for i in issues if i["severity"] == "error"]
        assert any(c in case.codes for c in errors), (name, case.why, case.codes, issues)
        assert rss < MAX_RSS_MB, f"{name}: validate used {rss:.0f} MB on a file of {os.path.getsize(case.path)} B"
        assert seconds < MAX_SECONDS, (name, seconds)


def test_voxfmt_inspect_refuses_each(cases: dict[str, Case]) -> None:
    for name, case in cases.items():
        code, _, err, rss, _ = run_with_rusage([VOXFMT, "inspect", case.path])
        assert code == case.exit, (name, code, err)
        assert any(c in err for c in case.codes) and case.path in err, (name, err)
        assert rss < MAX_RSS_MB, (name, rss)


def test_python_validate_reports_and_never_raises(cases: dict[str, Case]) -> None:
    for name, case in cases.items():
        report = voxfmt.validate(case.path)
        assert not report.valid, name
        assert any(i.code in case.codes for i in report.errors), (name, report.issues)
        for issue in report.issues:  # text, with a byte that was not UTF-8 escaped as \xNN
            assert isinstance(issue.message, str) and isinstance(issue.location, str)


def test_python_load_raises_a_coded_error(cases: dict[str, Case]) -> None:
    for name, case in cases.items():
        with pytest.raises(voxfmt.Error) as raised:
            voxfmt.load(case.path)
        assert raised.value.code in case.codes, (name, raised.value.code, str(raised.value))
        if case.exit == 2:
            assert isinstance(raised.value, voxfmt.InternalError), name


def test_a_name_that_is_not_utf8_is_escaped(cases: dict[str, Case]) -> None:
    report = voxfmt.validate(cases["group_name_not_utf8"].path)
    assert any(i.code == "UNKNOWN_OBJECT" and "\\xFF" in i.location for i in report.issues), report.issues


def test_the_budget_decides_and_can_be_raised(good: str) -> None:
    """A valid file needs more than 1 MiB (HDF5's own allowance): refused as over budget (exit 2, not judged
    invalid), then read with the default budget."""
    code, out, _, _, _ = run_with_rusage([VOXFMT, "validate", good, "--max-memory", "1", "--json"])
    assert code == 2, out
    assert [i["code"] for i in json.loads(out)["files"][0]["issues"]] == ["OUT_OF_MEMORY"], out
    assert "MiB" in out
    with pytest.raises(voxfmt.InternalError) as raised:
        voxfmt.load(good, max_memory_mib=1)
    assert raised.value.code == "OUT_OF_MEMORY"
    assert voxfmt.validate(good, max_memory_mib=1).errors[0].code == "OUT_OF_MEMORY"
    assert voxfmt.validate(good).valid
    voxfmt.load(good)
    with pytest.raises(voxfmt.OptionError):
        voxfmt.load(good, max_memory_mib=0)


def test_flipped_string_bytes_never_raise_anything_but_voxfmt_errors(good: str, tmp_path: Path) -> None:
    """Every byte of the strings of the root and the provenance, and of the group names, set to 0xFF in turn:
    validate() reports, load() accepts or raises a voxfmt.Error with a code, and the CLI agrees with Python."""
    flips = string_flips(good, tmp_path)
    assert len(flips) >= 40
    refused = 0
    for path in flips:
        report = voxfmt.validate(path)
        for issue in report.issues:
            assert isinstance(issue.message, str)
        try:
            voxfmt.load(path)
            loaded = True
        except voxfmt.Error as e:
            assert e.code, path
            loaded = False
        assert loaded == report.valid, (path, report.issues)
        cli = subprocess.run([VOXFMT, "validate", path], capture_output=True, text=True)
        assert (cli.returncode == 0) == report.valid, (path, cli.stdout)
        refused += not report.valid
    assert refused > len(flips) // 2, "most flips must damage the file: the test no longer hits the strings"


def test_a_folder_or_a_pipe_is_not_an_asset_for_any_consumer(tmp_path: Path) -> None:
    # fopen opens a folder on Linux (HDF5's read of it then failed with a dump of its internal state, NOT_HDF5)
    # and waits forever for a FIFO's writer.
    folder, pipe = tmp_path / "folder.vox.h5", tmp_path / "pipe.vox.h5"
    folder.mkdir()
    os.mkfifo(pipe)
    for path, words in ((str(folder), "a folder"), (str(pipe), "not a regular file")):
        for command in (["validate", path], ["inspect", path], ["export", path, "--nvdb", str(tmp_path / "x.nvdb")]):
            cli = subprocess.run([VOXFMT, *command], capture_output=True, text=True, timeout=60)
            assert cli.returncode == 2 and "FILE_NOT_FOUND" in cli.stdout + cli.stderr, (command, cli.stderr)
            assert words in cli.stdout + cli.stderr, (command, cli.stdout, cli.stderr)
        assert [i.code for i in voxfmt.validate(path).issues] == ["FILE_NOT_FOUND"]
        for read in (voxfmt.load, voxfmt.inspect):
            with pytest.raises(voxfmt.AssetError) as caught:
                read(path)
            assert caught.value.code == "FILE_NOT_FOUND", read
    for not_a_path in (None, 3):
        with pytest.raises(voxfmt.OptionError):
            voxfmt.load(not_a_path)  # type: ignore[arg-type]


def test_the_mujoco_plugin_names_the_code(cases: dict[str, Case]) -> None:
    try:
        import voxfmt.mujoco as vm

        vm.load_plugin()
    except Exception as e:  # a build without the plugin (no pinned mujoco wheel): nothing to test here
        pytest.skip(f"no MuJoCo plugin: {e}")
    sys.path.insert(0, str(REPO / "tests" / "mujoco"))
    from mujoco_child import compile_in_child

    results = compile_in_child([case.path for case in cases.values()])
    for (name, case), (_, error, message) in zip(cases.items(), results):
        assert error == "ValueError", (name, error, message)
        assert any(f"{c}:" in message for c in case.codes) and case.path in message, (name, message)
