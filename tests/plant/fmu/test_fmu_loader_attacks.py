"""FMUs that attack their loader (plant_emulator/fmu/extract.py,
plant_emulator/fmu/isolated_check.py, service_kit/crash_report.py): a zip
bomb, too many members, members leaving the extraction folder or that are
symlinks are refused in one line before a byte is extracted; an FMU that
crashes inside ``doStep`` (segmentation fault, abort) is one line naming the
FMU, the signal and the FMI call, never a silent death of ``ralf-hil up``
(in real time, with the controller's plant-fault policy acting:
tests/rig/test_plant_death.py)."""

from __future__ import annotations

import os
import shutil
import stat
import subprocess
import sys
import tempfile
import zipfile
from collections.abc import Iterator
from pathlib import Path

import pytest

from plant_emulator.fmu import extract
from plant_emulator.fmu.build import EXAMPLE_SOURCE, build_c_fmu
from plant_emulator.fmu.extract import ArchiveRefused, check_archive, extract_fmu
from plant_emulator.fmu.instance import FmuRefused
from plant_emulator.fmu.isolated_check import preflight_isolated
from service_kit.crash_report import crash_frames, death_line, fmi_call
from tests.plant.fmu.support import EXAMPLE_MAPPING, plant_settings, write_mapping
from workbench.progress import messages

CRASH_KINDS = {4: "segfault", 5: "abort"}


@pytest.fixture
def scratch(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """The extraction folder's parent, checked empty afterwards (nothing extracted, nothing left)."""
    folder = tmp_path / "scratch"
    folder.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(folder))
    yield folder
    assert list(folder.iterdir()) == []


def _with_members(src: Path, dest: Path, extra: list[tuple[zipfile.ZipInfo | str, bytes]], compression: int = zipfile.ZIP_DEFLATED) -> Path:
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dest, "w", compression) as zout:
        for item in zin.infolist():
            zout.writestr(item, zin.read(item))
        for info, data in extra:
            zout.writestr(info, data)
    return dest


def test_the_example_fmu_extracts_in_a_private_folder(two_mode_fmu: Path) -> None:
    folder = Path(extract_fmu(two_mode_fmu))
    try:
        assert stat.S_IMODE(folder.stat().st_mode) == 0o700
        with zipfile.ZipFile(two_mode_fmu) as zf:
            for info in zf.infolist():
                assert (folder / info.filename).read_bytes() == zf.read(info)
    finally:
        shutil.rmtree(folder)


def test_a_zip_bomb_is_refused_before_extracting(two_mode_fmu: Path, tmp_path: Path, scratch: Path) -> None:
    bomb = _with_members(two_mode_fmu, tmp_path / "bomb.fmu", [("resources/zeros.bin", bytes(64 * 1024 * 1024))])
    assert bomb.stat().st_size < 1024 * 1024  # 64 MiB of zeros in well under 1 MB
    with pytest.raises(ArchiveRefused, match=r"member 'resources/zeros.bin' expands \d+ times .* refused before extracting") as info:
        extract_fmu(bomb)
    assert str(bomb) in str(info.value) and "\n" not in str(info.value)


def test_an_fmu_extracting_past_the_total_limit_is_refused(two_mode_fmu: Path, tmp_path: Path, scratch: Path, monkeypatch: pytest.MonkeyPatch) -> None:

    big = _with_members(two_mode_fmu, tmp_path / "big.fmu", [("resources/noise.bin", os.urandom(3 * 1024 * 1024))])
    monkeypatch.setattr(extract, "MAX_TOTAL_BYTES", 2 * 1024 * 1024)
    with pytest.raises(ArchiveRefused, match="extracts to more than 2 MiB"):
        extract_fmu(big)


def test_an_fmu_of_too_many_members_is_refused(two_mode_fmu: Path, tmp_path: Path, scratch: Path) -> None:
    many = _with_members(two_mode_fmu, tmp_path / "many.fmu", [(f"resources/{i}.txt", b"") for i in range(extract.MAX_MEMBERS)], zipfile.ZIP_STORED)
    with pytest.raises(ArchiveRefused, match=f"more than the {extract.MAX_MEMBERS}"):
        extract_fmu(many)


def _symlink_member(name: str, target: str) -> tuple[zipfile.ZipInfo, bytes]:
    info = zipfile.ZipInfo(name)
    info.create_system = 3
    info.external_attr = (stat.S_IFLNK | 0o777) << 16
    return info, target.encode()


@pytest.mark.parametrize(
    ("member", "why"),
    [
        (("../escaped.txt", b"x"), "leaves the extraction folder"),
        (("resources/../../escaped.txt", b"x"), "leaves the extraction folder"),
        (("/tmp/escaped.txt", b"x"), "is an absolute path"),
        (("resources\\..\\escaped.txt", b"x"), "backslash"),
        (_symlink_member("resources/passwd", "/etc/passwd"), "is a symlink"),
        (_symlink_member("binaries", "/usr/lib"), "is a symlink"),
    ],
    ids=["dotdot", "nested-dotdot", "absolute", "backslash", "symlink-file", "symlink-folder"],
)
def test_members_outside_the_folder_or_symlinks_are_refused(
    two_mode_fmu: Path, tmp_path: Path, scratch: Path, member: tuple[zipfile.ZipInfo | str, bytes], why: str
) -> None:
    bad = _with_members(two_mode_fmu, tmp_path / "bad.fmu", [member])
    with pytest.raises(ArchiveRefused, match=why):
        extract_fmu(bad)
    assert not (tmp_path / "escaped.txt").exists() and not (scratch.parent / "escaped.txt").exists()


@pytest.mark.parametrize("target", ["/dev/zero", "fifo"])
def test_an_fmu_path_that_is_no_regular_file_says_what_it_is(tmp_path: Path, target: str) -> None:

    if target == "fifo":
        target = str(tmp_path / "plant.fmu")
        os.mkfifo(target)
    with pytest.raises(ArchiveRefused, match="is a (character device|FIFO), not a regular file"):
        check_archive(target)
    with pytest.raises(ArchiveRefused, match="no such FMU file"):
        check_archive(tmp_path / "absent.fmu")


# --- an FMU that crashes in its native code -----------------------------------------------


def _crashing_fmu(directory: Path) -> Path:
    """The example FMU with two more fault kinds: 4 dereferences NULL in doStep, 5 calls abort()."""
    src = directory / "crashing_src"
    shutil.copytree(EXAMPLE_SOURCE, src)
    c_file = src / "two_mode_plant.c"
    text = c_file.read_text()
    anchor = "    if (fault == 1) return fmi2Discard;\n"
    assert anchor in text
    crash = "    if (fault == 4) { volatile int *nowhere = 0; *nowhere = 1; }\n    if (fault == 5) abort();\n"
    c_file.write_text(text.replace(anchor, crash + anchor).replace("#include <math.h>", "#include <math.h>\n#include <stdlib.h>", 1))
    return build_c_fmu(src, directory / "crashing.fmu")


@pytest.fixture(scope="module")
def crashing_fmu(tmp_path_factory: pytest.TempPathFactory) -> Path:
    if shutil.which("gcc") is None:
        pytest.skip("no C compiler")
    return _crashing_fmu(tmp_path_factory.mktemp("crash"))


@pytest.mark.timeout(180)
@pytest.mark.parametrize(("kind", "signal_name"), [(4, "SIGSEGV"), (5, "SIGABRT")], ids=["segfault", "abort"])
def test_a_crash_in_the_checks_step_is_one_line_naming_the_fmu_and_the_call(crashing_fmu: Path, tmp_path: Path, kind: int, signal_name: str) -> None:
    mapping = write_mapping(tmp_path, parameters={"fault_step": 0, "fault_kind": kind})
    with pytest.raises(FmuRefused) as info:
        preflight_isolated(plant_settings(crashing_fmu, mapping))
    line = str(info.value)
    assert "\n" not in line
    assert line.startswith(f"{crashing_fmu}: crashed with {signal_name}") and "in fmi2DoStep" in line, line


@pytest.mark.timeout(180)
def test_ralf_hil_up_reports_a_crashing_fmu_in_one_line(crashing_fmu: Path, tmp_path: Path) -> None:
    """The check runs before any service (cosim: nothing starts): exit 2, one line, no −11."""
    mapping = write_mapping(tmp_path, parameters={"fault_step": 0, "fault_kind": 4})
    proc = subprocess.run(
        [sys.executable, "-m", "workbench", "up", "--clock", "cosim", "--duration", "1", "--rig-id", "crash"]
        + ["--set", f"plant.model=fmu:{crashing_fmu}", "--set", f"plant.fmu_mapping={mapping}"],
        capture_output=True,
        text=True,
        timeout=170,
        check=False,
    )
    assert proc.returncode == 2, (proc.returncode, proc.stderr)
    lines = messages(proc.stderr)
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert "plant refused" in lines[0] and "SIGSEGV" in lines[0] and "fmi2DoStep" in lines[0] and str(crashing_fmu) in lines[0]


@pytest.mark.timeout(180)
def test_a_cosimulation_crashing_in_its_fmu_mid_run_is_one_line(crashing_fmu: Path, tmp_path: Path) -> None:
    """The check passes (the crash comes at step 50); the co-simulation runs in a child ``up``
    whose death is told by its parent: one line, exit 1, no faulthandler dump on stderr."""
    mapping = write_mapping(tmp_path, parameters={"fault_step": 50, "fault_kind": 4})
    proc = subprocess.run(
        [sys.executable, "-m", "workbench", "up", "--clock", "cosim", "--duration", "2", "--rig-id", "crash-cosim"]
        + ["--set", f"plant.model=fmu:{crashing_fmu}", "--set", f"plant.fmu_mapping={mapping}"],
        capture_output=True,
        text=True,
        timeout=170,
        check=False,
    )
    assert proc.returncode == 1, (proc.returncode, proc.stderr)
    assert f"rig failed: the co-simulation ended by SIGSEGV (Segmentation fault) in fmi2DoStep of FMU {crashing_fmu}" in proc.stderr, proc.stderr
    assert "Fatal Python error" not in proc.stderr and "Traceback" not in proc.stderr


FAULTHANDLER_DUMP = """\
some log line
Fatal Python error: Segmentation fault

Thread 0x00007f0000000001 (most recent call first):
  File "/x/threading.py", line 327 in wait

Current thread 0x00007f0000000000 (most recent call first):
  File "/x/plant_emulator/fmu/instance.py", line 210 in fmi2DoStep
  File "/x/plant_emulator/fmu/instance.py", line 240 in step
  File "/x/plant_emulator/fmu/plant.py", line 99 in advance

Extension modules: numpy.core._multiarray_umath (total: 1)
"""


def test_the_crash_line_is_read_from_a_faulthandler_dump() -> None:
    assert crash_frames(FAULTHANDLER_DUMP) == ["fmi2DoStep", "step", "advance"]
    assert fmi_call(FAULTHANDLER_DUMP) == "fmi2DoStep"
    assert death_line("plant", -11, FAULTHANDLER_DUMP, "/m/p.fmu") == "plant ended by SIGSEGV (Segmentation fault) in fmi2DoStep of FMU /m/p.fmu"
    assert death_line("dsp", -9, "") == "dsp ended by SIGKILL (Killed)"
    assert death_line("controller", 3) == "controller exited with 3"
    assert fmi_call("no dump here") is None


def test_the_example_fmu_still_passes_the_isolated_check(two_mode_fmu: Path) -> None:
    preflight_isolated(plant_settings(two_mode_fmu, EXAMPLE_MAPPING))


def test_an_extraction_left_by_a_crashed_process_is_removed_by_the_next(two_mode_fmu: Path, scratch: Path) -> None:
    ended = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True, check=True)
    orphan = scratch / f"ralf-fmu-{ended.stdout.strip()}-abcd1234"
    (orphan / "binaries").mkdir(parents=True)
    folder = Path(extract_fmu(two_mode_fmu))
    assert not orphan.exists() and folder.name.startswith(f"ralf-fmu-{os.getpid()}-")
    shutil.rmtree(folder)
