"""The docs' references to code by path, `dir/module.name` (docs/*.md, README.md): each names a function,
class or constant defined at the top level of the module at that path (a name moved to another module, or
never there, sends a reader to the wrong file)."""

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCS = sorted((ROOT / "docs").glob("*.md")) + [ROOT / "README.md"]
REFERENCE = re.compile(r"`((?:[a-z_]+/)+[a-z_]+)\.([A-Za-z_][A-Za-z0-9_]*)`")
SOURCES = [p for folder in ("systems", "diagrams", "benchmarks", "models") for p in (ROOT / folder).rglob("*.py")]


def references() -> list[tuple[str, str, str]]:
    """(document, module path, name) for every `dir/module.name` in the docs, but file names (`x/y.py`)."""
    found = []
    for doc in DOCS:
        for module, name in REFERENCE.findall(doc.read_text()):
            if name not in ("py", "md", "yaml", "json", "npz", "onnx", "png", "txt", "csv", "html"):
                found.append((doc.name, module, name))
    return found


def top_level_names(path: Path) -> set[str]:
    names = set()
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.Assign):
            names.update(t.id for t in node.targets if isinstance(t, ast.Name))
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            names.add(node.target.id)
    return names


def test_the_docs_name_code_by_path():
    assert len(references()) >= 10


@pytest.mark.parametrize("document, module, name", references(), ids=lambda v: str(v))
def test_a_path_reference_names_what_that_module_defines(document, module, name):
    modules = [p for p in SOURCES if p.relative_to(ROOT).as_posix().endswith(f"{module}.py")]
    assert len(modules) == 1, f"{document}: `{module}.{name}`: {len(modules)} modules at {module}.py"
    assert name in top_level_names(modules[0]), f"{document}: {modules[0].relative_to(ROOT)} defines no {name}"
