"""The project as a user installs it: `pip install .` (a wheel, not the source tree), used from
a directory that has nothing to do with the project, with relative paths for every input and
output."""

from __future__ import annotations

import json
import tomllib
import zipfile
from pathlib import Path

import pytest
from conftest import run_installed as _run

from haptic_local_model.shared import __version__

REPO = Path(__file__).resolve().parent.parent
CODE_ROOTS = ("shared", "sim_server", "haptic_server", "device_models", "benchmarks", "api")
NAMESPACE = "haptic_local_model"


def test_the_package_list_is_the_tree() -> None:
    """pyproject.toml lists the packages by hand, each under the one installed name
    (configs/ is mapped into `shared`): a package added to the tree and not to the list would
    be missing from every install."""
    setuptools = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    code = {
        ".".join((NAMESPACE, *p.parent.relative_to(REPO).parts))
        for root in CODE_ROOTS
        for p in (REPO / root).rglob("__init__.py")
    }
    data = {f"{NAMESPACE}.shared.configs"} | {
        f"{NAMESPACE}.shared.configs.{d.name}" for d in (REPO / "configs").iterdir() if d.is_dir()
    }
    assert set(setuptools["packages"]) == code | data
    assert setuptools["package-dir"] == {
        **{f"{NAMESPACE}.{root}": root for root in CODE_ROOTS},
        f"{NAMESPACE}.shared.configs": "configs",
    }


@pytest.mark.processes
def test_the_wheel_installs_one_top_level_name(wheel: Path) -> None:
    """Nothing lands in site-packages under a generic name (`shared`, `benchmarks`) another
    project could also use: every file of the wheel is under haptic_local_model/ or its
    metadata, and the shipped configs are inside."""
    names = zipfile.ZipFile(wheel).namelist()
    tops = {n.split("/")[0] for n in names}
    assert tops == {NAMESPACE, f"{NAMESPACE}-{__version__}.dist-info"}, tops
    assert f"{NAMESPACE}/shared/configs/scenes/testbed.toml" in names
    assert f"{NAMESPACE}/__init__.py" not in names  # a namespace: other distributions may extend it


def test_the_version_is_the_distribution_s() -> None:
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    assert __version__ == project["version"]


@pytest.mark.slow
@pytest.mark.processes
def test_the_wheel_runs_from_any_directory(
    installed: Path, tmp_path: Path, network_file: Path
) -> None:
    """`haptic-run` in real time and on the virtual clock, `haptic-replay`, `haptic-bench
    --quick`: from an unrelated directory, with a scene, log and summary given by relative
    paths; each exits 0 and writes where it was asked, nothing into the install."""
    work = tmp_path / "elsewhere"
    work.mkdir()
    where = _run(
        installed, work, "python", "-c", "import haptic_local_model.shared as s; print(s.__file__)"
    )
    assert where.returncode == 0, where.stderr
    assert str(installed) in where.stdout, where.stdout  # the wheel's code, not the tree's
    site = Path(where.stdout.strip()).parent.parent
    before = _files(site)
    (work / "my_scene.toml").write_text((REPO / "configs/scenes/wall_push.toml").read_text())
    (work / "net.toml").write_text(network_file.read_text())  # loopback, a free port

    listed = _run(installed, work, "haptic-run", "--list")
    assert listed.returncode == 0, listed.stderr
    assert "testbed" in listed.stdout and "twin_pantograph" in listed.stdout
    version = _run(installed, work, "haptic-replay", "--version")
    assert version.stdout.strip().endswith(f"{__version__} (haptic-local-model)")

    # the virtual clock first: it loads (or compiles) most kernels in one process
    common = ["--scene", "my_scene.toml", "--user", "push_2n", "--network", "net.toml"]
    virtual = _run(
        installed, work, "haptic-run", "--clock", "virtual", *common, "--duration", "2",
        "--log", "out/virtual.mcap", "--summary-json", "out/virtual.json",
    )  # fmt: skip
    assert virtual.returncode == 0, virtual.stderr + virtual.stdout
    assert json.loads((work / "out/virtual.json").read_text())["ticks"] == 2000

    real = _run(
        installed, work, "haptic-run", *common, "--duration", "3",
        "--log", "out/real.mcap", "--summary-json", "out/real.json",
    )  # fmt: skip
    assert real.returncode == 0, real.stderr + real.stdout
    summary = json.loads((work / "out/real.json").read_text())
    assert summary["exit_codes"] == {"haptic": 0, "sim": 0}
    assert summary["updates_received"] > 60  # the sim's updates arrived over 3 s at 60 Hz
    assert (work / "out/real.mcap").stat().st_size > 0

    replay = _run(installed, work, "haptic-replay", "out/virtual.mcap", "--no-progress")
    assert replay.returncode == 0, replay.stderr + replay.stdout
    assert "identical" in replay.stdout

    bench = _run(installed, work, "haptic-bench", "--quick", "--out", "out/bench")
    assert bench.returncode == 0, bench.stderr + bench.stdout
    assert (work / "out/bench/report.md").is_file()

    # nothing was written into the installed packages (logs, caches, reports)
    assert _files(site) - before == set()


def _files(site: Path) -> set[Path]:
    """The installed project's files, bytecode aside."""
    return {
        p
        for root in CODE_ROOTS
        for p in (site / root).rglob("*")
        if p.is_file() and "__pycache__" not in p.parts
    }


#: every console script with a config or usage error a user makes: a scene file that is not
#: there, a device with an unknown key, a log that is not there, an option out of range
BAD_CALLS = {
    "haptic-run": ("--scene", "missing.toml", "--duration", "1"),
    "haptic-run --clock virtual": ("--clock", "virtual", "--device", "bad.toml", "--duration", "1"),
    "haptic-server": ("--scene", "missing.toml"),
    "sim-server": ("--scene", "bad.toml"),
    "haptic-replay": ("missing.mcap",),
    "haptic-soak": ("--no-such-option",),
    "haptic-bench": ("--out", "x", "--no-such-option"),
    "haptic-stability": ("--rates", "fast"),
    "haptic-pointer": ("--events", "missing.jsonl"),
    "haptic-router": ("--network", "missing.toml"),
    "haptic-world": ("--scene", "missing.toml"),
    "haptic-station": ("--port", "left", "--scene", "missing.toml"),
    "haptic-device": ("check", "--device", "missing.toml"),
}


@pytest.mark.processes
@pytest.mark.parametrize("call", sorted(BAD_CALLS))
def test_the_installed_scripts_fail_in_one_line(installed: Path, tmp_path: Path, call: str) -> None:
    """On the non-editable install, from a directory of the user's: exit 2, no traceback, the
    last line names what was wrong."""
    (tmp_path / "bad.toml").write_text('model = "ideal"\nbogus_key = 1\n')
    out = _run(installed, tmp_path, call.split()[0], *BAD_CALLS[call], timeout=300)
    assert out.returncode == 2, (call, out.stdout, out.stderr)
    assert "Traceback" not in out.stderr + out.stdout, out.stderr
    last = out.stderr.strip().splitlines()[-1]
    named = ("missing.toml", "bad.toml", "missing.mcap", "--no-such-option", "--rates",
             "missing.jsonl")  # fmt: skip
    assert any(n in last for n in named), last
