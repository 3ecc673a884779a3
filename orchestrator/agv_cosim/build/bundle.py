"""What goes into an FMU's ``resources/``: the part of ``agv_core`` a slave script reaches,
and the Python distributions that code imports.

Derived, not listed by hand:

- **Modules.** The slave script names the core modules it needs in its
  ``load_core("fmi.fmi_slave", "vehicle.vehicle", ...)`` call (string literals, checked).
  From those, every relative import is followed through the package (``ast``, whole
  files, so imports inside functions count too). The bundle is the modules reached plus
  the ``__init__.py`` of every package on their way: nothing else of ``agv_core`` is
  shipped. A module of the bundle may not import ``agv_core`` absolutely, nor import
  dynamically (``importlib.import_module``, ``__import__``): the walk could not follow.
- **Distributions.** The absolute imports met on the way (in the slave script, the boot
  loader and the bundled modules, e.g. ``numpy``, ``scipy.sparse``, ``skfuzzy.control``,
  ``pythonfmu``) are imported in a fresh child process of the building Python; every
  module that this loads (the packages' own imports as well, e.g. scikit-fuzzy's
  ``packaging`` and ``networkx``, which scikit-fuzzy does not declare) is mapped to the
  distribution that installed it (``importlib.metadata.packages_distributions``), but for
  the wrapper's own package (pythonfmu / pythonfmu3), which the FMU carries. Each is
  pinned to the version installed at build time (``name==version``): the FMU's shipped
  reference result was computed with exactly these, and ``pip install --no-deps -r
  requirements.txt`` into an empty venv gives a Python that runs the FMU
  (tests/packaging/test_fmu_requirements.py does that for every FMU).

The bundle's tag (``agv_core_bundle/BUILD_ID``, the module name ``agv_core_<tag>`` the boot
loader gives it) is a hash of the bundled files as staged and of the requirement list.
"""

import ast
import functools
import hashlib
import importlib.metadata
import json
import re
import subprocess
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from ..errors import BundleError

__all__ = ["Bundle", "BundleError", "bundle_of", "installed_requirements",
           "requirements_text"]


#: (direct, indirect) distributions of an FMU, each sorted ((name, version), ...).
Requirements = tuple[tuple[tuple[str, str], ...], tuple[tuple[str, str], ...]]


@dataclass(frozen=True)
class Bundle:
    """What one FMU ships of ``agv_core`` and what it needs installed."""

    #: bundled files, paths relative to the ``agv_core`` folder (posix), sorted
    files: tuple[str, ...]
    #: absolute imports of the FMU's code (dotted names as written), sorted
    imports: tuple[str, ...]
    #: distributions the FMU's code imports itself: ((name, version), ...), sorted
    direct: tuple[tuple[str, str], ...]
    #: distributions that those import when they load (not already in ``direct``)
    indirect: tuple[tuple[str, str], ...]
    #: content hash of the staged files and the requirements (16 hex digits)
    tag: str


def _parse(source: str, where: str) -> ast.Module:
    try:
        return ast.parse(source, filename=where)
    except SyntaxError as error:
        raise BundleError(f"{where}: {error}") from None


def _load_core_arguments(tree: ast.AST, where: str) -> list[str]:
    """The submodule names of the ``load_core(...)`` calls of a slave script."""
    names: list[str] = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        func = node.func
        called = func.id if isinstance(func, ast.Name) else getattr(func, "attr", None)
        if called != "load_core":
            continue
        for arg in node.args:
            if not (isinstance(arg, ast.Constant) and isinstance(arg.value, str)):
                raise BundleError(f"{where}: load_core takes string literals only (the "
                                  "build derives the bundle from them)")
            names.append(arg.value)
        if node.keywords:
            raise BundleError(f"{where}: load_core takes no keyword arguments")
    return names


def _absolute_imports(tree: ast.AST) -> list[str]:
    """Dotted names of the absolute imports in ``tree``; for ``from X import Y`` both
    ``X`` and ``X.Y`` (Y may be a submodule; the child process tells)."""
    return list(_imports_of(tree).absolute)


@dataclass(frozen=True)
class _Imports:
    """The import statements of one source, from one pass over its tree."""

    absolute: tuple[str, ...]   # dotted names, as _absolute_imports says
    # (line, level, module or None, (names...)) of `from .x import ...`
    relative: tuple[tuple[int, int, str | None, tuple[str, ...]], ...]
    own: int          # line of an absolute import of agv_core (0: none)
    dynamic: int      # line of an importlib.import_module / __import__ call (0: none)


def _imports_of(tree: ast.AST) -> "_Imports":
    absolute: list[str] = []
    relative: list[tuple[int, int, str | None, tuple[str, ...]]] = []
    own, dynamic = 0, 0
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
            absolute += names
        elif isinstance(node, ast.ImportFrom) and node.level == 0:
            module = node.module or ""  # an absolute `from X import` always names X
            names = [module]
            absolute.append(module)
            absolute += [f"{module}.{alias.name}" for alias in node.names
                         if alias.name != "*"]
        elif isinstance(node, ast.ImportFrom):
            relative.append((node.lineno, node.level, node.module,
                             tuple(alias.name for alias in node.names)))
            continue
        elif isinstance(node, ast.Call):
            func = node.func
            if not dynamic and ((isinstance(func, ast.Name) and func.id == "__import__") or (
                    isinstance(func, ast.Attribute) and func.attr == "import_module")):
                dynamic = node.lineno
            continue
        else:
            continue
        if not own and any(n == "agv_core" or n.startswith("agv_core.") for n in names):
            own = node.lineno
    return _Imports(tuple(absolute), tuple(relative), own, dynamic)


@functools.cache
def _module_imports(text: str, where: str) -> _Imports:
    """:class:`_Imports` of a package module's source (parsed once per process)."""
    return _imports_of(_parse(text, where))


class _CoreView:
    """The package's files as the FMU will hold them (``overrides``: relative path ->
    text that replaces or adds a file, e.g. the FMI 3.0 alias of ``fmi/fmi_slave.py``)."""

    def __init__(self, core_dir: Path, overrides: Iterable[tuple[str, str]]) -> None:
        self.core_dir = Path(core_dir)
        self.overrides = dict(overrides)

    def exists(self, relative: str) -> bool:
        return relative in self.overrides or (self.core_dir / relative).is_file()

    def text(self, relative: str) -> str:
        if relative in self.overrides:
            return self.overrides[relative]
        return (self.core_dir / relative).read_text(encoding="utf-8")

    def module_file(self, dotted: str) -> str | None:
        """The file of module ``dotted`` (relative to the package), or None."""
        parts = [p for p in dotted.split(".") if p]
        if not parts:
            return "__init__.py"
        for candidate in ("/".join(parts) + ".py", "/".join(parts) + "/__init__.py"):
            if self.exists(candidate):
                return candidate
        return None


def _package_of(relative: str) -> str:
    """Dotted package (relative to agv_core) that the module file ``relative`` is in."""
    return ".".join(relative[:-3].split("/")[:-1])  # a/b.py and a/__init__.py: "a"


def _walk(view: _CoreView, roots: list[str], where: str) -> tuple[list[str], list[str]]:
    """Files of the package reached from the module names ``roots``; absolute imports."""
    pending: list[str] = []
    files: set[str] = set()
    external: list[str] = []
    for name in roots:
        relative = view.module_file(name)
        if relative is None:
            raise BundleError(f"{where}: load_core names '{name}', which is not a module "
                              "of agv_core")
        pending.append(relative)
    while pending:
        relative = pending.pop()
        if relative in files:
            continue
        files.add(relative)
        # every package on the way is executed on import: its __init__.py is needed
        package = _package_of(relative).split(".") if _package_of(relative) else []
        for k in range(len(package) + 1):
            init = "/".join([*package[:k], "__init__.py"])
            if view.exists(init):
                pending.append(init)
        found = _module_imports(view.text(relative), f"agv_core/{relative}")
        if found.dynamic:
            raise BundleError(f"agv_core/{relative}:{found.dynamic}: a dynamic import; the "
                              "build cannot tell which modules it needs")
        if found.own:
            raise BundleError(f"agv_core/{relative}:{found.own}: an absolute import of "
                              "agv_core; inside the package every import is relative (the "
                              "FMU loads it under another name)")
        external += found.absolute
        for line, level, module, names in found.relative:
            base = _package_of(relative).split(".") if _package_of(relative) else []
            if level - 1 > len(base):
                raise BundleError(f"agv_core/{relative}:{line}: relative import beyond the "
                                  "package")
            base = base[:len(base) - (level - 1)]
            target = ".".join([*base, *(module.split(".") if module else [])])
            module_file = view.module_file(target)
            if module_file is None:
                raise BundleError(f"agv_core/{relative}:{line}: no module "
                                  f"'{target or '__init__'}' in agv_core")
            pending.append(module_file)
            for name in names:  # `from . import paths`: a submodule, if it is one
                sub = view.module_file(f"{target}.{name}" if target else name)
                if sub is not None and name != "*":
                    pending.append(sub)
    return sorted(files), external


#: Run in a child of the building Python: import the given names, print the distributions
#: that the modules now loaded come from ("found"), and which of them provide the
#: top-level packages of the names themselves ("direct").
_PROBE = r"""
import importlib, importlib.metadata as md, json, sys, sysconfig
from pathlib import Path
names = json.loads(sys.argv[1])
before = set(sys.modules)
for name in names:
    try:
        importlib.import_module(name)
    except ModuleNotFoundError as error:
        # `from X import Y` where Y is a name in X, not a submodule: not an import
        if error.name == name and "." in name and name.rpartition(".")[0] in sys.modules:
            continue
        print(json.dumps({"missing": name, "error": str(error)}))
        sys.exit(0)
stdlib = [Path(sysconfig.get_paths()[k]).resolve() for k in ("stdlib", "platstdlib")]
roots = sorted({Path(p).resolve() for p in sys.path if p and Path(p).is_dir()},
               key=lambda p: -len(p.parts))
owners = md.packages_distributions()
wanted = {n.partition(".")[0] for n in names}
tops, unowned = {}, set()  # top-level name of a distribution's files -> wanted?
for name in (set(sys.modules) - before) | {n for n in names if n in sys.modules}:
    top = name.partition(".")[0]
    where = getattr(sys.modules[name], "__file__", None)
    if top in sys.stdlib_module_names or where is None:
        continue  # the standard library, or built into the interpreter or an extension
    if top not in owners:
        # an extension module registered under a name of its own (scipy's
        # _csparsetools): the top-level name is its file's first part below its root
        path = Path(where).resolve()
        if any(path.is_relative_to(s) for s in stdlib) and "site-packages" not in path.parts:
            continue
        root = next((r for r in roots if path.is_relative_to(r)), None)
        top = path.relative_to(root).parts[0].split(".")[0] if root else None
        if top not in owners:
            unowned.add(f"{name} ({path})")
            continue
    tops[top] = tops.get(top, False) or name.partition(".")[0] in wanted
found, direct, provides = {}, set(), {}
for top, is_wanted in tops.items():
    for dist in owners[top]:
        meta = md.distribution(dist)
        found[meta.metadata["Name"]] = meta.version
        provides.setdefault(meta.metadata["Name"], []).append(top)
        if is_wanted:
            direct.add(meta.metadata["Name"])
unowned = sorted(unowned)
print(json.dumps({"found": found, "direct": sorted(direct), "provides": provides,
                  "unowned": unowned}))
"""


@functools.cache
def _distributions(python: str, names: tuple[str, ...], shipped: tuple[str, ...] = ()
                   ) -> tuple[tuple[tuple[str, str], ...], tuple[tuple[str, str], ...]]:
    """(direct, indirect): the distributions providing ``names`` themselves, and those
    their loading brings in besides, each as sorted ((name, version), ...); leaving out
    those whose every top-level package is in ``shipped`` (the FMU carries them)."""
    done = subprocess.run([python, "-I", "-c", _PROBE, json.dumps(list(names))],
                          capture_output=True, text=True, timeout=300)
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or [f"exit code {done.returncode}"])[-1]
        raise BundleError(f"cannot import the FMU's packages to list them: {last}")
    answer = json.loads(done.stdout.strip().splitlines()[-1])
    if "missing" in answer:
        raise BundleError(f"the FMU's code imports '{answer['missing']}', which this "
                          f"Python cannot import: {answer['error']}")
    if answer["unowned"]:
        raise BundleError("no installed distribution provides the module(s) "
                          f"{', '.join(answer['unowned'])} that the FMU's code loads")

    def ordered(pairs: Iterable[tuple[str, str]]) -> tuple[tuple[str, str], ...]:
        return tuple(sorted(pairs, key=lambda kv: kv[0].lower()))

    found = {d: v for d, v in answer["found"].items()
             if not set(answer["provides"][d]) <= set(shipped)}
    return (ordered((d, found[d]) for d in answer["direct"] if d in found),
            ordered((d, v) for d, v in found.items() if d not in answer["direct"]))


def bundle_of(script: Path, core_dir: Path, overrides: Iterable[tuple[str, str]] = (),
              extra_sources: Sequence[str | Path] = (), local: Iterable[str] = (),
              shipped: Iterable[str] = (), requirements: Requirements | None = None,
              python: str | None = None) -> Bundle:
    """The :class:`Bundle` of slave script ``script`` over the package in ``core_dir``.

    ``overrides``: (path relative to the package, text) pairs that the FMU holds instead
    of (or besides) the package's files. ``extra_sources``: other top-level files shipped
    with the script (the boot loader) whose absolute imports count too. ``local``: names
    of top-level modules the FMU ships itself (the boot loader, the script, the FMI 3.0
    body), not looked up among the installed distributions. ``shipped``: top-level
    packages that the FMU carries in its ``resources/`` (pythonfmu copies itself there):
    what they import counts, their own distributions are not listed. ``requirements``: (direct,
    indirect) to take instead of importing the packages in a child process (see
    :func:`installed_requirements`). ``python``: the interpreter whose installed
    distributions are listed (default: this one).
    """
    script = Path(script)
    view = _CoreView(core_dir, overrides)
    tree = _parse(script.read_text(encoding="utf-8"), script.name)
    roots = _load_core_arguments(tree, script.name)
    files, external = _walk(view, roots, script.name)
    external += _absolute_imports(tree)
    for source in extra_sources:
        external += _absolute_imports(_parse(Path(source).read_text(encoding="utf-8"),
                                             Path(source).name))
    own = {script.stem, *(Path(p).stem for p in extra_sources), *local}
    imports = tuple(sorted({n for n in external if n.partition(".")[0] not in own
                            and n.partition(".")[0] not in sys.stdlib_module_names}))
    direct: Sequence[tuple[str, str]]
    indirect: Sequence[tuple[str, str]]
    if requirements is not None:
        direct, indirect = requirements
    elif imports:
        direct, indirect = _distributions(python or sys.executable, imports,
                                          tuple(sorted(shipped)))
    else:
        direct, indirect = (), ()
    digest = hashlib.sha256()
    for relative in files:
        digest.update(relative.encode() + b"\0" + view.text(relative).encode() + b"\0")
    digest.update(requirements_text(direct, indirect).encode())
    return Bundle(tuple(files), imports, tuple(direct), tuple(indirect),
                  digest.hexdigest()[:16])


def installed_requirements(text: str) -> Requirements | None:
    """(direct, indirect) of a ``requirements.txt`` written by :func:`requirements_text`,
    or None if it is not one or if some pinned version is not the one installed in this
    Python (then the list must be derived again)."""
    if not text or not text.startswith(_HEADER[0]):
        return None
    groups: dict[str, list[tuple[str, str]]] = {"direct": [], "indirect": []}
    current = None
    for line in text.splitlines():
        if line == _DIRECT:
            current = "direct"
        elif line == _INDIRECT:
            current = "indirect"
        elif line and not line.startswith("#"):
            name, sep, version = line.partition("==")
            if not sep or current is None or _installed().get(_normal(name)) != version:
                return None
            groups[current].append((name, version))
    return tuple(groups["direct"]), tuple(groups["indirect"])


def _normal(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


@functools.lru_cache(maxsize=1)
def _installed() -> dict[str, str]:
    """Normalised distribution name -> version, of this Python (read once per process)."""
    versions: dict[str, str] = {}
    for dist in importlib.metadata.distributions():
        versions.setdefault(_normal(dist.metadata["Name"] or ""), dist.version)
    return versions


_HEADER = ("# Python distributions this FMU's code imports, derived by agv-cosim build",
           "# from the imports of its slave script and bundled modules, pinned to the",
           "# versions it was built and its reference result computed with.",
           "# Install with: pip install --no-deps -r requirements.txt")
_DIRECT = "# imported by the FMU's own code:"
_INDIRECT = "# imported by those when they load:"


def requirements_text(direct: Sequence[tuple[str, str]],
                      indirect: Sequence[tuple[str, str]]) -> str:
    """``requirements.txt`` of an FMU: its distributions pinned, in two commented groups."""
    lines = [*_HEADER, _DIRECT]
    lines += [f"{name}=={version}" for name, version in direct]
    if not direct and not indirect:
        lines.append("# (none: the standard library and what the FMU carries suffice)")
    if indirect:
        lines.append(_INDIRECT)
        lines += [f"{name}=={version}" for name, version in indirect]
    return "\n".join(lines) + "\n"
