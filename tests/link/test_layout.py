"""link/ laid out by what it is (issue 32): the radio profile, the acoustic profile as a
package of its own, transports, emulators; one events module per profile, each
event a frozen dataclass of its profile's base class; no two classes of link/ share
a name; no module of link/ imports another that imports it back, even lazily."""

from __future__ import annotations

import ast
import dataclasses
import inspect
from pathlib import Path

import pytest

from rovlink.link.acoustic import events as acoustic_events
from rovlink.link.radio import events as radio_events

LINK = Path(__file__).resolve().parents[2] / "link"


def _modules() -> dict[str, Path]:
    out = {}
    for path in LINK.rglob("*.py"):
        parts = path.relative_to(LINK).with_suffix("").parts
        name = ".".join(p for p in parts if p != "__init__")
        out[name] = path
    return out


def test_the_folders_say_what_they_hold():
    subpackages = {p.name for p in LINK.iterdir() if p.is_dir() and (p / "__init__.py").exists()}
    assert {"radio", "acoustic", "transports", "emulators"} <= subpackages
    assert not (LINK / "acoustic.py").exists()


@pytest.mark.parametrize("module, base", [(radio_events, radio_events.RadioEvent),
                                          (acoustic_events, acoustic_events.AcousticEvent)])
def test_each_profile_has_one_events_module_of_frozen_dataclasses_with_a_base(module, base):
    classes = [c for _, c in inspect.getmembers(module, inspect.isclass) if c.__module__ == module.__name__]
    events = [c for c in classes if c is not base]
    assert len(events) >= 10
    for cls in events:
        assert issubclass(cls, base) and dataclasses.is_dataclass(cls), cls
        assert cls.__dataclass_params__.frozen, cls


def test_no_two_classes_of_link_share_a_name():
    seen: dict[str, str] = {}
    clashes = []
    for name, path in _modules().items():
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, ast.ClassDef) and not node.name.startswith("_"):
                if node.name in seen:
                    clashes.append(f"{node.name}: {seen[node.name]} and {name}")
                seen[node.name] = name
    assert not clashes, clashes


def test_no_import_circle_in_link():
    modules = _modules()
    graph: dict[str, set[str]] = {name: set() for name in modules}
    for name, path in modules.items():
        package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
        for node in ast.walk(ast.parse(path.read_text())):  # every import, lazy ones in functions too
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package[: len(package) - (node.level - 1)]
                    target = ".".join(base + ([node.module] if node.module else []))
                elif node.module and node.module.startswith("rovlink.link."):
                    target = node.module[len("rovlink.link."):]
                else:
                    continue
                candidates = [target] + [f"{target}.{a.name}" if target else a.name for a in node.names]
                graph[name] |= {c for c in candidates if c in modules and c != name}
    # A package's __init__ gathering its own modules is no circle of theirs.
    for name in graph:
        graph[name] = {t for t in graph[name] if not (t and name.startswith(t + "."))}

    def reach(start: str) -> set[str]:
        seen, todo = set(), [start]
        while todo:
            for nxt in graph[todo.pop()]:
                if nxt not in seen:
                    seen.add(nxt)
                    todo.append(nxt)
        return seen

    circles = sorted(name for name in graph if name in reach(name))
    assert not circles, circles
