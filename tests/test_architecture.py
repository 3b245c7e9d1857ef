"""The package's layers, enforced by walking every import in its source (module level and inside
functions alike).

core (data model, errors, units, time, head pose, files, model protocol)
  -> numerics (shared solvers and signal tools) -> render (pictures) -> io (every file format)
  -> targets (what a character's keys are: meshes, controls, skeletons, drawings)
  -> methods (cloning, retarget, style, headmotion, capture, transfer; none imports another)
  -> characters (a user's character: read, landmarks, drive rig, generated shapes)
  -> evaluation (metrics, datasets) -> applications (pipelines) -> cli

A module may import only from its own layer or below; a private module (``pkg._mod``) only from
inside its package; and no group of modules may import each other in a cycle.  See
``docs/architecture.md``.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "faceretarget"
ROOT = "faceretarget"

CORE = {"__init__", "errors", "units", "timebase", "names", "mesh", "rig", "character", "headpose", "performance", "files",
        "base", "optional", "formats"}
LAYERS = {**{m: 0 for m in CORE}, "numerics": 1, "render": 2, "io": 3, "targets": 3.5,
          "cloning": 4, "retarget": 4, "style": 4, "headmotion": 4, "capture": 4, "transfer": 4,
          "characters": 4.5, "metrics": 5, "datasets": 5, "pipelines": 6, "cli": 7}
METHODS = {"cloning", "retarget", "style", "headmotion", "capture", "transfer"}


def _module_name(path: Path) -> str:
    rel = path.relative_to(SRC.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _is_package(path: Path) -> bool:
    return path.name == "__init__.py"


def _resolve(module: str, is_pkg: bool, node: ast.ImportFrom) -> list[str]:
    """Absolute names a ``from ... import ...`` refers to (a submodule when one exists)."""
    if node.level:
        base = module.split(".") if is_pkg else module.split(".")[:-1]
        base = base[: len(base) - (node.level - 1)]
        target = ".".join(base + ([node.module] if node.module else []))
    else:
        target = node.module or ""
    out = []
    for alias in node.names:
        sub = f"{target}.{alias.name}"
        out.append(sub if _exists(sub) else target)
    return out


def _exists(name: str) -> bool:
    if not name.startswith(ROOT):
        return False
    rel = Path(*name.split(".")[1:]) if "." in name else Path()
    return (SRC / rel).with_suffix(".py").is_file() or (SRC / rel / "__init__.py").is_file()


def import_graph(src: Path = SRC) -> dict[str, set[str]]:
    """``{module: {faceretarget modules it imports}}`` for every module under ``src``."""
    graph: dict[str, set[str]] = {}
    for path in sorted(src.rglob("*.py")):
        mod = _module_name(path)
        deps: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            if isinstance(node, ast.Import):
                deps.update(a.name for a in node.names if a.name.split(".")[0] == ROOT)
            elif isinstance(node, ast.ImportFrom):
                deps.update(d for d in _resolve(mod, _is_package(path), node) if d.split(".")[0] == ROOT)
        deps.discard(mod)
        graph[mod] = deps
    return graph


def unit_of(module: str) -> str:
    """The layer unit of a module: the subpackage, or the core module's name."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def layer_violations(graph: dict[str, set[str]]) -> list[str]:
    bad = []
    for mod, deps in graph.items():
        u = unit_of(mod)
        if u not in LAYERS:
            bad.append(f"{mod}: not in any layer (add it to LAYERS and docs/architecture.md)")
            continue
        for d in deps:
            v = unit_of(d)
            if v not in LAYERS:
                continue
            if LAYERS[v] > LAYERS[u]:
                bad.append(f"{mod} (layer {LAYERS[u]}) imports {d} (layer {LAYERS[v]})")
            elif u in METHODS and v in METHODS and u != v:
                bad.append(f"{mod} imports {d}: methods must not import each other")
    return sorted(bad)


def private_violations(graph: dict[str, set[str]]) -> list[str]:
    """A private module ``faceretarget.pkg._mod`` (or a private core module) used outside its package."""
    bad = []
    for mod, deps in graph.items():
        for d in deps:
            parts = d.split(".")
            priv = [i for i, p in enumerate(parts) if p.startswith("_") and not p.startswith("__")]
            if not priv:
                continue
            owner = ".".join(parts[: priv[0]])
            if not (mod == owner or mod.startswith(owner + ".")) or owner == ROOT:
                bad.append(f"{mod} imports the private module {d}")
    return sorted(bad)


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle (a list of modules, first repeated at the end), or None."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(n: str) -> list[str] | None:
        state[n] = 1
        stack.append(n)
        for m in sorted(graph.get(n, ())):
            if state.get(m) == 1:
                return stack[stack.index(m):] + [m]
            if state.get(m) is None:
                c = visit(m)
                if c:
                    return c
        stack.pop()
        state[n] = 2
        return None

    for n in sorted(graph):
        if state.get(n) is None:
            c = visit(n)
            if c:
                return c
    return None


def unit_graph(graph: dict[str, set[str]]) -> dict[str, set[str]]:
    """Subpackages and core modules as nodes (a package's own modules folded into it)."""
    g: dict[str, set[str]] = {}
    for mod, deps in graph.items():
        u = unit_of(mod)
        g.setdefault(u, set()).update(unit_of(d) for d in deps if unit_of(d) != u)
    return g


def module_graph_without_package_inits(graph: dict[str, set[str]]) -> dict[str, set[str]]:
    """Module graph with the edges into a package's own ``__init__`` removed (its re-exports), so a
    cycle here is a cycle between real modules."""
    pkgs = {m for m in graph if (SRC.parent / Path(*m.split("."))).is_dir()}
    g = {}
    for mod, deps in graph.items():
        g[mod] = {d for d in deps if not (d in pkgs and mod.startswith(d + "."))}
    return g


@pytest.fixture(scope="module")
def graph():
    return import_graph()


def test_every_module_is_in_a_layer_and_imports_only_downwards(graph):
    assert len(graph) > 60
    assert layer_violations(graph) == []


def test_no_private_module_is_imported_from_outside_its_package(graph):
    assert private_violations(graph) == []


def test_no_import_cycle_between_layers_or_modules(graph):
    assert find_cycle(unit_graph(graph)) is None
    assert find_cycle(module_graph_without_package_inits(graph)) is None


def test_the_checks_catch_what_they_are_for(graph):
    """A reintroduced cloning <-> retarget cycle, a method reaching into another, a private import
    across packages and a core module importing a method are all reported."""
    g = {k: set(v) for k, v in graph.items()}
    g["faceretarget.cloning._keysets"].add("faceretarget.retarget._retargeter")
    g["faceretarget.retarget._retargeter"].add("faceretarget.cloning._features")
    g["faceretarget.performance"].add("faceretarget.style")
    bad = layer_violations(g) + private_violations(g)
    assert any("methods must not import each other" in b for b in bad)
    assert any(b.startswith("faceretarget.performance (layer 0) imports faceretarget.style") for b in bad)
    assert any("private module faceretarget.cloning._features" in b for b in bad)
    assert find_cycle(unit_graph(g)) is not None
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None


def test_relative_imports_resolve_to_real_modules(graph):
    missing = sorted(f"{m} -> {d}" for m, deps in graph.items() for d in deps if not _exists(d))
    assert missing == []


def extension_literals(src: Path = SRC) -> list[str]:
    """``file:line '.ext'`` for every string constant that is exactly a file extension the registry declares
    (:mod:`faceretarget.formats`), outside the registry itself (a file name built in an f-string, such as
    ``f"{name}.obj"``, is not a format decision)."""
    from faceretarget import formats

    known = {v for k, v in vars(formats).items() if k.isupper() and isinstance(v, str) and v.startswith(".")}
    known |= {e for v in vars(formats).values() if isinstance(v, tuple) for e in v
              if isinstance(e, str) and e.startswith(".")}
    out = []
    for path in sorted(src.rglob("*.py")):
        if path == src / "formats.py":
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"))
        in_fstring = {id(v) for n in ast.walk(tree) if isinstance(n, ast.JoinedStr) for v in n.values}
        for node in ast.walk(tree):
            if id(node) not in in_fstring and isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value.lower() in known:
                out.append(f"{path.relative_to(src)}:{node.lineno} {node.value!r}")
    return out


def test_every_file_extension_is_declared_only_in_the_format_registry(tmp_path):
    """Issue 33: one place answers which formats, which route, what is needed; the check catches a literal."""
    assert extension_literals() == []
    (tmp_path / "m.py").write_text('OUT = "x"\nif OUT.endswith(".usda"):\n    pass\n')
    assert extension_literals(tmp_path) == ["m.py:2 '.usda'"]


def test_each_character_format_is_one_declaration_that_answers_everything():
    from faceretarget import formats, io

    seen = set()
    for f in formats.CHARACTER_FORMATS.values():
        assert not seen & set(f.extensions), f"{f.name}: an extension declared twice"
        seen |= set(f.extensions)
        assert callable(formats._resolve(f.reader)), f.reader            # the reader it names exists
        for w in (f.animation_writer, f.shapes_writer):
            assert not w or callable(formats._resolve(w)), w
        for e in f.extensions:
            assert formats.character_format_of(f"x{e.upper()}") is f
            assert io.character_format(f"x{e}") == f.name
        for out in f.writes_back:
            assert io.writes_back(f"x{f.extensions[0]}", f"y{out}")
        assert not io.writes_back(f"x{f.extensions[0]}", "y.csv") if f.extensions else True
    assert set(io.CHARACTER_EXTENSIONS) == seen
    assert io.WRITE_BACK["vrm0"] == io.WRITE_BACK["vrm1"] == formats.CHARACTER_FORMATS["vrm"].writes_back
    assert io.SHAPES_WRITE is io.WRITE_BACK                        # was a second, hand-kept copy
    assert formats.character_format_of(SRC) is formats.CHARACTER_FORMATS["obj"]     # a folder
    assert formats.character_format_of("take.csv") is None


def test_io_all_is_what_a_user_calls():
    """``faceretarget.io.__all__`` (the API page lists exactly it) holds at most 60 names: the readers and
    writers of each format, the data classes they return and the format lists.  Every name exists and is
    documented (a docstring of its own; a format list in the package docstring), and none is a helper of the
    Blender extension's scene steps, the extension registry, the glTF document or a re-export of
    ``faceretarget.files`` (those stay importable as ``faceretarget.io.name``, outside ``__all__``)."""
    import inspect

    import faceretarget.io as io

    names = io.__all__
    assert len(names) <= 60, f"{len(names)} names in faceretarget.io.__all__"
    assert len(set(names)) == len(names)
    undocumented = []
    for n in names:
        obj = getattr(io, n)
        if callable(obj):
            doc = inspect.getdoc(obj) or ""
            own = obj.__doc__ is not None and not doc.startswith(f"{n}(")   # not a dataclass's generated signature
            if not (doc.strip() and own):
                undocumented.append(n)
        elif f"``{n}``" not in io.__doc__:
            undocumented.append(n)
    assert undocumented == []
    internal = {"scene_character_steps", "scene_action_steps", "character_objects", "run_steps", "head_bones", "HeadBone",
                "read_blender_scene_character", "GltfDocument", "READERS", "WRITERS", "register_reader",
                "register_writer", "read_glb_rig"}
    assert internal.isdisjoint(names)
    assert all(hasattr(io, n) for n in internal)                           # still importable for the other packages
    home = {n: getattr(getattr(io, n), "__module__", None) for n in names}
    assert [n for n, m in home.items() if m in ("faceretarget.io._blender_scene", "faceretarget.files")] == []


def long_functions(src: Path = SRC, limit: int = 150) -> list[str]:
    """Functions longer than ``limit`` lines whose docstring does not say why (a sentence with "Long because")."""
    out = []
    for path in sorted(src.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                n = node.end_lineno - node.lineno + 1
                if n > limit and "Long because" not in (ast.get_docstring(node) or ""):
                    out.append(f"{path.relative_to(src)}:{node.lineno} {node.name} ({n} lines)")
    return out


def test_no_function_over_150_lines_without_a_reason(tmp_path):
    """Issue 33: ``animate`` and ``generate_shapes`` read as short stories; a long function says why."""
    assert long_functions() == []
    body = "\n".join(f"    x{i} = {i}" for i in range(160))
    (tmp_path / "m.py").write_text(f"def f():\n{body}\n")
    assert long_functions(tmp_path) == ["m.py:1 f (161 lines)"]
    import faceretarget.characters._generate as gen
    import faceretarget.pipelines._animate as an

    for mod, name, most in ((an, "animate", 60), (gen, "generate_shapes", 60)):
        tree = ast.parse(Path(mod.__file__).read_text(encoding="utf-8"))
        fn = next(n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == name)
        assert fn.end_lineno - fn.lineno + 1 <= most, name
