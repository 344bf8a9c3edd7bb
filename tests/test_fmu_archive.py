"""An FMU's archive is checked before anything is extracted (part of issue 37): an
entry that would unpack outside its folder, or an archive that unpacks to more than
evo-door allows (a zip bomb: a megabyte that claims gigabytes), is refused in one line,
quickly, with little memory (before: 2.1 GB taken before failing)."""

from __future__ import annotations

import time
import tracemalloc
import zipfile

import pytest

from evo_door.cli import main
from evo_door.models.fmu.description import MAX_UNPACKED

DESCRIPTION = '<?xml version="1.0"?><fmiModelDescription fmiVersion="2.0" modelName="x"/>'


def _one_line(capsys) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("evo-door: error:"), err
    return err


def test_a_zip_bomb_fmu_is_refused_before_extraction(tmp_path, capsys):
    path = tmp_path / "bomb.fmu"
    chunk = bytes(2**20)
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("modelDescription.xml", DESCRIPTION)
        with z.open("resources/zeros.bin", "w", force_zip64=True) as out:
            for _ in range(MAX_UNPACKED // len(chunk) + 8):
                out.write(chunk)
    assert path.stat().st_size < 4 * 2**20  # a few MiB on disk
    tracemalloc.start()
    t0 = time.perf_counter()
    assert main(["params", str(path)]) == 2
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert time.perf_counter() - t0 < 5.0 and peak < 50 * 2**20
    assert "unpacks to more than" in _one_line(capsys)


@pytest.mark.parametrize("entry", ["../escape.txt", "/etc/evil", "binaries/../../up.so"])
def test_an_fmu_entry_outside_its_folder_is_refused(tmp_path, capsys, entry):
    path = tmp_path / "escape.fmu"
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("modelDescription.xml", DESCRIPTION)
        z.writestr(entry, "x")
    assert main(["params", str(path)]) == 2
    assert "outside its folder" in _one_line(capsys)
