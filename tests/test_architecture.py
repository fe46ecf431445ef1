"""The import graph of the project's packages: no circle, and no import that runs up the layers.

Layers, bottom to top (a module may import its own layer and those below):

0. contracts and helpers: ``capture`` (package), ``capture._malloc``, ``capture.events``, ``capture.cliargs``
1. libraries: the RAW codec ``capture.raw``, the drivers ``capture.evk`` and ``capture.gopro``, the
   session store ``capture.session``, the per-flight results ``capture.results``, ``calib``
2. ``detect``, ``spin``, ``sim``, ``capture.ingest``, the Rerun review ``capture.review``
3. the pipeline layer ``capture.pipeline`` (the only one that joins devices, detect and spin)
4. command lines: ``capture.run``, ``capture.replay``, ``capture.batch``, ``capture.report``, ``capture.cli``, every ``cli`` and
   ``__main__``

Imports inside functions count as much as those at the top of a module.
"""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("capture", "detect", "spin", "calib", "sim")


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for pkg in PACKAGES for p in sorted((ROOT / pkg).rglob("*.py"))}


def import_graph() -> dict[str, set[str]]:
    """Module -> the project modules it imports (``from a import b`` is module ``a.b`` when that is
    a module, else ``a``)."""
    mods = _modules()
    graph = {}
    for name, path in mods.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        targets = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets |= {a.name for a in node.names}
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    anchor = package.split(".")[:len(package.split(".")) - (node.level - 1)]
                    base = ".".join(anchor + ([node.module] if node.module else []))
                targets |= {f"{base}.{a.name}" if f"{base}.{a.name}" in mods else base for a in node.names}
        graph[name] = {t for t in targets if t.split(".")[0] in PACKAGES and t != name}
    return graph


def layer(module: str) -> int:
    parts = module.split(".")
    if module in ("capture.run", "capture.replay", "capture.batch", "capture.report", "capture.cli") or parts[-1] in ("cli", "__main__"):
        return 4
    if module.startswith("capture.pipeline"):
        return 3
    if parts[0] in ("detect", "spin", "sim") or module.startswith(("capture.ingest", "capture.review")):
        return 2
    if module in ("capture", "capture._malloc", "capture.events", "capture.cliargs"):
        return 0
    return 1


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Import circles: the strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on_stack, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in graph:
        if v not in index:
            visit(v)
    return out


@pytest.fixture(scope="module")
def graph():
    return import_graph()


def test_the_graph_sees_known_imports(graph):
    # the walker itself: a relative import, a function-level import and a package import
    assert "capture.evk.errors" in graph["capture.evk.device"]
    assert "capture.pipeline.replay" in graph["capture.run"]
    assert "capture.events" in graph["detect.track"]


def test_no_import_circle(graph):
    assert cycles(graph) == []
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]  # the check works


def test_no_import_runs_up_the_layers(graph):
    upward = sorted(f"{m} (layer {layer(m)}) imports {t} (layer {layer(t)})"
                    for m, targets in graph.items() for t in targets if layer(t) > layer(m))
    assert upward == []


def test_only_the_pipeline_and_command_lines_join_detect_and_spin(graph):
    joined = sorted(f"{m} imports {t}" for m, targets in graph.items() for t in targets
                    if t.split(".")[0] in ("detect", "spin") and m.split(".")[0] != t.split(".")[0]
                    and layer(m) < 3)
    assert joined == []


def test_the_raw_codec_stands_alone(graph):
    codec = {m: t for m, t in graph.items() if m.startswith("capture.raw") and layer(m) < 4}
    outside = sorted(f"{m} imports {t}" for m, targets in codec.items() for t in targets
                     if not t.startswith("capture.raw") and t not in ("capture", "capture.events"))
    assert codec and outside == []


def test_replay_without_a_review_does_not_load_rerun():
    """``python -m capture.replay`` imports Rerun's SDK (0.3 s of its 0.8 s start) only to write a review."""
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[1]
    code = "import sys, capture.replay; print('rerun' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
