"""The type stubs (`python/subterra/_core.pyi`) cover the compiled extension: every class and
every public method or property of it, so editors and type checkers see the whole API."""

from __future__ import annotations

import ast
from pathlib import Path

import subterra._core as core

STUBS = Path(core.__file__).with_name("_core.pyi")


def _stub_classes() -> dict[str, set[str]]:
    tree = ast.parse(STUBS.read_text(encoding="utf-8"))
    classes = {}
    for node in tree.body:
        if isinstance(node, ast.ClassDef):
            names = set()
            for item in node.body:
                if isinstance(item, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    names.add(item.name)
                elif isinstance(item, ast.AnnAssign) and isinstance(item.target, ast.Name):
                    names.add(item.target.id)
            for base in node.bases:  # members a stub class inherits from a stub base (`_Config`)
                if isinstance(base, ast.Name) and base.id in classes:
                    names |= classes[base.id]
            classes[node.name] = names
    return classes


def test_every_extension_class_and_member_has_a_stub():
    stubs = _stub_classes()
    missing = []
    for name in dir(core):
        cls = getattr(core, name)
        if name.startswith("_") or not isinstance(cls, type):
            continue
        if name not in stubs:
            missing.append(name)
            continue
        for member in dir(cls):
            if not member.startswith("_") and member not in stubs[name]:
                missing.append(f"{name}.{member}")
    assert not missing, f"not in {STUBS.name}: {', '.join(missing)}"
