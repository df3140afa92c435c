"""rovlink installs as one import name, and the ROV side installs without the
console's extra.

The wheel is built from a copy of the checkout (so that no build/ or
egg-info lands in it), offline, with the setuptools and wheel the test extra
installs.  The base install is proven in a fresh virtual environment without
the system's site-packages: it sees only the distributions that rovlink's
base requirements name (found through their metadata, recursively, and linked
in from this environment, since there is no package index to install from in
a test), so `pip check` there says whether the base requirements suffice, and
viser, FastAPI and the rest of the console extra are truly absent.
"""

from __future__ import annotations

import email
import importlib.metadata
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from packaging.requirements import Requirement

from tests.helpers import free_tcp_port

pytestmark = pytest.mark.slow

CHECKOUT = Path(__file__).resolve().parents[1]
CONSOLE_EXTRA = {"viser", "fastapi", "uvicorn", "websockets", "trimesh", "matplotlib"}


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    src = tmp_path_factory.mktemp("src")
    tracked = subprocess.run(["git", "ls-files", "-z"], cwd=CHECKOUT, capture_output=True, check=True).stdout
    for name in filter(None, tracked.decode().split("\0")):
        if (CHECKOUT / name).is_file():
            (src / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(CHECKOUT / name, src / name)
    out = tmp_path_factory.mktemp("wheel")
    build = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index",
         "--disable-pip-version-check", "-q", "-w", str(out), str(src)],
        capture_output=True, text=True, timeout=300)
    assert build.returncode == 0, build.stderr[-2000:]
    (path,) = out.glob("rovlink-*.whl")
    return path


def _metadata(wheel: Path) -> email.message.Message:
    with zipfile.ZipFile(wheel) as z:
        (name,) = [n for n in z.namelist() if n.endswith(".dist-info/METADATA")]
        return email.message_from_bytes(z.read(name))


def test_the_wheel_adds_one_top_level_name(wheel):
    with zipfile.ZipFile(wheel) as z:
        names = z.namelist()
    tops = {n.split("/")[0] for n in names}
    assert {t for t in tops if not t.endswith(".dist-info")} == {"rovlink"}
    # Every folder is there under the one name, with its data.
    for expected in ("rovlink/__main__.py", "rovlink/cli.py", "rovlink/command.py", "rovlink/link/radio/frame.py",
                     "rovlink/link/cli.py", "rovlink/link/acoustic/operator.py",
                     "rovlink/link/emulators/m64serial.py", "rovlink/debt/cli.py", "rovlink/rov/cli.py",
                     "rovlink/console/commands/demo.py", "rovlink/console/web/routers/ws.py",
                     "rovlink/console/scene/app.py", "rovlink/console/web/static/index.html",
                     "rovlink/assets/rov.glb", "rovlink/assets/seabed.json",
                     "rovlink/assets/images/seabed.png"):
        assert expected in names, expected
    with zipfile.ZipFile(wheel) as z:
        top_level = [n for n in names if n.endswith("entry_points.txt")]
        assert "rovlink = rovlink.cli:main" in z.read(top_level[0]).decode()


def test_the_base_requirements_leave_the_console_extra_out(wheel):
    meta = _metadata(wheel)
    base, console = set(), set()
    for line in meta.get_all("Requires-Dist"):
        req = Requirement(line)
        if req.marker is None:
            base.add(req.name.lower())
        elif req.marker.evaluate({"extra": "console"}):
            console.add(req.name.lower())
    assert base == {"numpy", "numba", "pyserial", "pymavlink", "pillow", "wlmodem"}
    assert console == CONSOLE_EXTRA
    assert "console" in meta.get_all("Provides-Extra")


def _base_distributions(wheel: Path) -> list[importlib.metadata.Distribution]:
    """This environment's distributions that rovlink's base requirements need,
    following their own requirements (extras left out, markers evaluated)."""
    todo = [Requirement(r) for r in _metadata(wheel).get_all("Requires-Dist")
            if Requirement(r).marker is None]
    found: dict[str, importlib.metadata.Distribution] = {}
    while todo:
        req = todo.pop()
        name = req.name.lower()
        if name in found or (req.marker is not None and not req.marker.evaluate({"extra": ""})):
            continue
        dist = importlib.metadata.distribution(name)
        found[name] = dist
        todo.extend(Requirement(r) for r in dist.requires or ())
    return list(found.values())


@pytest.fixture(scope="module")
def base_venv(wheel, tmp_path_factory) -> Path:
    """A new venv holding rovlink's wheel and only its base requirements."""
    root = tmp_path_factory.mktemp("base")
    venv = root / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=120)
    python = venv / "bin" / "python"
    site = Path(subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               capture_output=True, text=True, check=True).stdout.strip())
    linked = root / "linked"
    linked.mkdir()
    for dist in _base_distributions(wheel):
        base = Path(dist.locate_file(""))
        for top in {Path(str(f)).parts[0] for f in dist.files or ()}:
            if top != ".." and not (linked / top).exists() and (base / top).exists():
                (linked / top).symlink_to(base / top)
    (site / "rovlink-base-requirements.pth").write_text(f"{linked}\n")
    install = subprocess.run([str(python), "-m", "pip", "install", "--no-deps", "--no-index", "-q",
                              "--disable-pip-version-check", str(wheel)],
                             capture_output=True, text=True, timeout=300)
    assert install.returncode == 0, install.stderr[-2000:]
    return venv


def _run(venv: Path, *args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    # From an empty folder, so that the checkout's own folders are not on the path.
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    return subprocess.run(args, capture_output=True, text=True, timeout=timeout, cwd=venv.parent, env=env)


def test_the_base_install_is_complete_and_has_no_console(base_venv):
    python = str(base_venv / "bin" / "python")
    check = _run(base_venv, python, "-m", "pip", "check", "--disable-pip-version-check")
    assert check.returncode == 0, check.stdout + check.stderr
    assert _run(base_venv, python, "-c", "import rovlink.link, rovlink.debt, rovlink.rov").returncode == 0
    for absent in ("viser", "fastapi", "console", "link", "rov", "debt", "assets"):
        out = _run(base_venv, python, "-c", f"import {absent}")
        assert out.returncode != 0 and "ModuleNotFoundError" in out.stderr, absent


def test_the_base_install_runs_the_rov_side(base_venv):
    rovlink = str(base_venv / "bin" / "rovlink")
    for command in (["rov", "--help"], ["sim", "--help"], ["channel", "--help"], ["keygen", "--help"],
                    ["debt", "encode", "--help"]):
        out = _run(base_venv, rovlink, *command)
        assert out.returncode == 0, (command, out.stderr)
        assert "usage: rovlink" in out.stdout
    # `python -m rovlink` is the same command.
    assert "rov" in _run(base_venv, str(base_venv / "bin" / "python"), "-m", "rovlink", "--help").stdout


def test_the_base_install_runs_the_simulated_vehicle(base_venv):
    """`rovlink sim` from the base install talks MAVLink to a ground station."""
    from pymavlink import mavutil

    port = free_tcp_port()
    gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", dialect="ardupilotmega")
    sim = subprocess.Popen([str(base_venv / "bin" / "rovlink"), "sim", "--mavlink", f"udpout:127.0.0.1:{port}",
                            "--status-every", "0"], cwd=base_venv.parent, stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True)
    try:
        heartbeat = gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=30)
        assert heartbeat is not None, sim.stderr.read() if sim.poll() is not None else "no heartbeat"
        assert heartbeat.type == mavutil.mavlink.MAV_TYPE_SUBMARINE
    finally:
        sim.terminate()
        sim.wait(timeout=10)
        gcs.close()


@pytest.mark.parametrize("command", [["demo"], ["console", "--link", "udp://127.0.0.1:1?peer=127.0.0.1:2"],
                                     ["replay", "x.jsonl"], ["plot", "x.jsonl"], ["bench", "console"]])
def test_console_commands_without_the_extra_say_how_to_install_it(base_venv, command):
    out = _run(base_venv, str(base_venv / "bin" / "rovlink"), *command)
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1, out.stderr
    assert "python3 -m pip install 'rovlink[console]'" in lines[0]
    assert "Traceback" not in out.stderr


def test_the_checkout_does_not_shadow_other_distributions():
    """Outside the checkout, `console` (a real distribution's name) is not ours."""
    out = subprocess.run([sys.executable, "-c", "import console"], capture_output=True, text=True,
                         cwd="/", timeout=60)
    assert out.returncode != 0
    out = subprocess.run([sys.executable, "-c", "import rovlink.console.commands.demo, rovlink.link.radio.frame as f; print(f.__name__)"],
                         capture_output=True, text=True, cwd="/", timeout=60)
    assert out.stdout.strip() == "rovlink.link.radio.frame", out.stderr


# Which rovlink packages each folder may import (ARCHITECTURE.md): `link` and
# `debt` know nothing of ROVs, browsers or each other; nothing below the
# console imports the console.  `rovlink.command` is the commands' shared kit,
# `rovlink.bench` the benchmarks' output.
ALLOWED_IMPORTS = {
    "link": {"rovlink.link", "rovlink.command", "rovlink.bench"},
    "debt": {"rovlink.debt", "rovlink.command", "rovlink.bench", "rovlink.assets"},  # the bench's sample images
    "rov": {"rovlink.rov", "rovlink.link", "rovlink.debt", "rovlink.assets", "rovlink.command", "rovlink.bench"},
    "rovlink": {"rovlink.command", "rovlink.cli", "rovlink.link"},  # link_key reads key files
}


@pytest.mark.parametrize("folder", sorted(ALLOWED_IMPORTS))
def test_packages_import_only_what_the_architecture_allows(folder):
    import ast

    allowed = ALLOWED_IMPORTS[folder]
    wrong = []
    for path in sorted((CHECKOUT / folder).rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module] if node.module != "rovlink" else [f"rovlink.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            else:
                continue
            for name in names:
                if name.split(".")[0] in ("rovlink", "link", "debt", "rov", "console", "assets") and not any(
                        name == a or name.startswith(a + ".") for a in allowed):
                    wrong.append(f"{path.name}:{node.lineno} imports {name}")
    assert not wrong, wrong
