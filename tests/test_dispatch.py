"""The `rovlink` dispatcher (rovlink/cli.py): a command imports its own
package only, so the ROV's base install (no console extra) runs `rovlink rov`
without ever importing the console; `--help` and a wrong name still list
every command."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from rovlink import cli

CONSOLE_EXTRA = ("viser", "fastapi", "uvicorn", "starlette", "websockets", "trimesh", "matplotlib")

# Runs the dispatcher in a fresh interpreter, then says which modules were imported.
PROBE = """
import json, sys
from rovlink.cli import main
try:
    main(sys.argv[1:])
except SystemExit:
    pass
print("MODULES " + json.dumps(sorted(sys.modules)), file=sys.stderr)
"""


def _imported(*args: str) -> list[str]:
    out = subprocess.run([sys.executable, "-c", PROBE, *args], capture_output=True, text=True, timeout=120)
    (line,) = [ln for ln in out.stderr.splitlines() if ln.startswith("MODULES ")]
    assert "usage: rovlink" in out.stdout, out.stdout + out.stderr
    return json.loads(line[len("MODULES "):])


def _console_parts(modules: list[str]) -> list[str]:
    return [m for m in modules if m.startswith("rovlink.console") or m.split(".")[0] in CONSOLE_EXTRA]


@pytest.mark.parametrize("args", [["rov", "--help"], ["sim", "--help"], ["keygen", "--help"],
                                  ["channel", "--help"], ["debt", "encode", "--help"],
                                  ["bench", "link", "--help"], ["bench", "debt", "--help"],
                                  ["bench", "camera", "--help"], ["bench", "roi", "--help"]])
def test_the_rov_side_commands_import_nothing_of_the_console(args):
    modules = _imported(*args)
    assert _console_parts(modules) == []
    assert (cli.BENCHMARKS[args[1]] if args[0] == "bench" else cli.COMMANDS[args[0]]) in modules


@pytest.mark.parametrize("args", [["console", "--help"], ["bench", "console", "--help"]])
def test_the_console_commands_import_their_own_module(args):
    modules = _imported(*args)
    assert "rovlink.console.commands.console" in modules or "rovlink.console.bench.console" in modules


def test_python_m_rovlink_rov_imports_nothing_of_the_console():
    """The real entry, `python -m rovlink rov --help` (rovlink/__main__.py), run by runpy as -m does."""
    probe = ("import json, runpy, sys\n"
             "sys.argv = ['rovlink', 'rov', '--help']\n"
             "try:\n"
             "    runpy.run_module('rovlink', run_name='__main__', alter_sys=True)\n"
             "except SystemExit as exc:\n"
             "    assert exc.code == 0, exc.code\n"
             "print('MODULES ' + json.dumps(sorted(sys.modules)), file=sys.stderr)\n")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert "usage: rovlink rov" in out.stdout, out.stderr[-2000:]
    (line,) = [ln for ln in out.stderr.splitlines() if ln.startswith("MODULES ")]
    modules = json.loads(line[len("MODULES "):])
    assert "rovlink.rov.cli" in modules
    assert _console_parts(modules) == []


def test_help_lists_every_command_of_the_table_in_its_order(capsys):
    with pytest.raises(SystemExit) as done:
        cli.main(["--help"])
    assert done.value.code == 0
    text = capsys.readouterr().out.split("COMMAND\n", 1)[1].split("\n\n", 1)[0]
    listed = [line.split()[0] for line in text.splitlines() if line.startswith("    ") and not line.startswith("     ")]
    assert listed == list(cli.COMMANDS)


@pytest.mark.parametrize("name", list(cli.COMMANDS))
def test_each_command_is_found_by_its_own_name(name, capsys):
    """The table names the module that really defines each command."""
    with pytest.raises(SystemExit) as done:
        cli.main([name, "--help"])
    assert done.value.code == 0
    assert capsys.readouterr().out.startswith(f"usage: rovlink {name}")


@pytest.mark.parametrize("name", list(cli.BENCHMARKS))
def test_each_benchmark_is_found_by_its_own_name(name, capsys):
    with pytest.raises(SystemExit) as done:
        cli.main(["bench", name, "--help"])
    assert done.value.code == 0
    assert capsys.readouterr().out.startswith(f"usage: rovlink bench {name}")


@pytest.mark.parametrize("args, listed", [(["rovv"], "'rov', 'sim'"), (["bench", "lnk"], "'link', 'console', 'debt'")])
def test_a_wrong_name_is_one_line_listing_the_choices(args, listed):
    out = subprocess.run([sys.executable, "-m", "rovlink", *args], capture_output=True, text=True, timeout=120)
    assert out.returncode == 2
    (line,) = out.stderr.strip().splitlines()
    assert "invalid choice" in line and listed in line
