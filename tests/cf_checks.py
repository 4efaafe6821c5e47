"""The CF checker as the tests run it (tests/storage, tests/face and tests/solve use it): one module
at the tests' root, importable however a test is started (a test file importing another test file
worked only after that file had been collected)."""

from pathlib import Path

import pytest

CF_TABLES = Path(__file__).resolve().parent / "data" / "cf"


def cf_counts(path: Path, tmp_path: Path) -> dict[str, int]:
    """cfchecker's counts on `path` with the offline tables of tests/data/cf.

    cfchecker 4.1 (the latest) knows CF versions up to 1.8; the files say CF-1.10, whose
    additions (1.9, 1.10) none of them uses, so 1.10 is registered and checked with
    every rule cfchecker has. It reads only the root group of a netCDF-4 file and wants
    a .nc name: a run file is checked as it is (root attributes), and each of its groups
    as a flat copy with the root's attributes."""
    try:
        from cfchecker import cfchecks
    except (ImportError, OSError) as exc:  # cfunits raises OSError without libudunits2
        pytest.skip(f"cfchecker not usable here ({type(exc).__name__}: {exc}); `make cf-tools` installs it")
    version = cfchecks.CFVersion((1, 10))
    if version not in cfchecks.cfVersions:
        cfchecks.cfVersions.append(version)
    if path.suffix != ".nc":
        copy = tmp_path / (path.stem + ".nc")
        copy.write_bytes(path.read_bytes())
        path = copy
    checker = cfchecks.CFChecker(
        cfStandardNamesXML=str(CF_TABLES / "cf-standard-name-table.xml"),
        cfAreaTypesXML=str(CF_TABLES / "area-type-table.xml"),
        cfRegionNamesXML=str(CF_TABLES / "standardized-region-list.xml"),
        version=version, silent=True,
    )
    checker.checker(str(path))
    return dict(checker.get_total_counts())
