"""Imports point down and never go round: read from the source with ``ast``, nothing imported.

Every ``import`` of every module under ``src/aslexp`` counts: at module level, inside functions,
and under ``if TYPE_CHECKING:``. ``from aslexp.x import y`` is an import of the module
``aslexp.x.y`` when that is a module, else of ``aslexp.x``. The package ``__init__`` that Python
runs before any submodule is not counted as imported (else every package would be a circle with
its own re-exports).

A room is a folder under ``src/aslexp`` or a top-level module (``files``, ``errors``, ...); the
package's own ``__init__`` is the room ``aslexp``. :data:`LEVELS` is the house, as data: a room
imports only rooms on a lower level (and itself). Two rooms on one level do not import each other.
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[2] / "src" / "aslexp"

# cli -> jobs -> results -> (runs, reports) -> (recognition, envs, rl, tuning) -> (data, pose, sim, keypoints)
# -> foundation
LEVELS: dict[str, int] = {
    # foundation: leaf modules any room may use
    "errors": 0, "files": 0, "paths": 0, "process": 0, "quaternion": 0, "seeding": 0,
    "config_schema": 1,  # errors
    "compose": 1,        # errors, paths: group names composed by Hydra's loader as the jobs compose them
    "plugins": 1,        # errors: entry points and registering modules, for every registry
    "runfile": 1,        # files: run.json's name, time stamps, marking a run interrupted
    "viz": 1,            # files: plots and videos, the only room that imports matplotlib
    # the ground floor
    "keypoints": 2,      # the bottom room
    "data": 3,           # keypoints
    "sim": 3,
    "pose": 4,           # keypoints, data, sim, viz
    # the wings
    "recognition": 5,
    "envs": 5,
    "rl": 5,             # imports no environment: evaluation takes any env with ImitationEnv's interface
    "tuning": 5,         # a sweep reads run.json through runfile, not through runs
    "signing": 6,        # a performance in its source's keypoints, scored (pose, keypoints) and read back (recognition); takes any env
    "runs": 6,           # run records and readers, runs list/diff, sweep reports, the folder report (recognition)
    "reports": 6,        # the imitation sweep tables: they read run folders, nothing of envs, sim or rl
    "measure": 7,        # what simulates and learns nothing (baselines, engine agreement): envs, rl; run configs via reports
    "results": 7,        # the results page: reads run folders (runs) and the wings' tables (reports, recognition)
    "control": 6,        # planners (model-predictive control): build batched envs (envs)
    # the edge
    "jobs": 8,
    "tools": 8,
    "cli": 9,
    "aslexp": 10,         # the package's __init__: registers the gymnasium environments (envs)
}


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module_name(path): path for path in sorted(PACKAGE.rglob("*.py"))}


def import_graph() -> dict[str, dict[str, int]]:
    """module -> {imported aslexp module: line of the first such import}."""
    modules = _modules()
    graph: dict[str, dict[str, int]] = {}
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        edges: dict[str, int] = {}

        def add(target: str, line: int) -> None:
            if target != name and target.split(".")[0] == "aslexp":
                edges.setdefault(target, line)

        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
            if isinstance(node, ast.Import):
                for alias in node.names:
                    add(alias.name, node.lineno)
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")[: len(package.split(".")) - node.level + 1]
                    source = ".".join(base + ([node.module] if node.module else []))
                else:
                    source = node.module or ""
                named = [f"{source}.{alias.name}" for alias in node.names]
                submodules = [target for target in named if target in modules]
                for target in submodules:
                    add(target, node.lineno)
                if len(submodules) < len(named):  # some names are attributes of ``source`` itself
                    add(source, node.lineno)
        graph[name] = edges
    return graph


def room(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def cycles(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(start: str) -> None:  # iterative: no recursion limit to meet
        work = [(start, iter(graph.get(start, ())))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, successors = work[-1]
            for nxt in successors:
                if nxt not in graph:
                    continue
                if nxt not in index:
                    index[nxt] = low[nxt] = len(index)
                    stack.append(nxt)
                    on_stack.add(nxt)
                    work.append((nxt, iter(graph.get(nxt, ()))))
                    break
                if nxt in on_stack:
                    low[node] = min(low[node], index[nxt])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = []
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.append(member)
                        if member == node:
                            break
                    if len(component) > 1:
                        found.append(sorted(component))

    for module in sorted(graph):
        if module not in index:
            visit(module)
    return found


def test_every_module_parses_and_imports_only_existing_aslexp_modules():
    graph = import_graph()
    assert len(graph) > 50 and "aslexp.keypoints.registry" in graph
    missing = [f"{module} -> {target}" for module, edges in graph.items() for target in edges if target not in graph]
    assert not missing, f"imports of aslexp modules that do not exist: {missing}"


def test_no_import_cycle_between_modules():
    found = cycles(import_graph())
    assert not found, "import circles (module-level, function-level and TYPE_CHECKING imports all count): " + \
        "; ".join(" <-> ".join(component) for component in found)


def room_graph(graph: dict[str, dict[str, int]]) -> dict[str, dict[str, int]]:
    rooms: dict[str, dict[str, int]] = {name: {} for name in LEVELS}
    for module, edges in graph.items():
        rooms.setdefault(room(module), {})
        for target in edges:
            if room(target) != room(module):
                rooms[room(module)].setdefault(room(target), 0)
    return rooms


def upward_imports(graph: dict[str, dict[str, int]]) -> list[str]:
    """Each import of a room on the importer's level or above, as ``module:line imports target``."""
    upward = []
    for module, edges in sorted(graph.items()):
        for target, line in sorted(edges.items()):
            low, high = room(target), room(module)
            if low != high and LEVELS.get(low, -1) >= LEVELS.get(high, -1):
                upward.append(f"{module}:{line} imports {target} "
                              f"({high} on level {LEVELS.get(high)}, {low} on {LEVELS.get(low)})")
    return upward


def test_no_import_cycle_between_rooms():
    found = cycles(room_graph(import_graph()))
    assert not found, "rooms that import each other: " + "; ".join(" <-> ".join(c) for c in found)


def test_every_room_has_a_level():
    rooms = {room(module) for module in _modules()}
    assert rooms == set(LEVELS), (f"rooms without a level (add them to LEVELS): {sorted(rooms - set(LEVELS))}; "
                                  f"levels of rooms that are gone: {sorted(set(LEVELS) - rooms)}")


def test_imports_point_down():
    upward = upward_imports(import_graph())
    assert not upward, "imports that do not point down:\n" + "\n".join(upward)


def test_the_checks_catch_the_seams_they_were_written_for():
    # On a made-up graph of the three seams once mended: a circle inside keypoints,
    # rl and envs importing each other, tuning importing runs.
    graph = {"aslexp.keypoints.registry": {"aslexp.keypoints.source": 30},
             "aslexp.keypoints.source": {"aslexp.keypoints.registry": 16},
             "aslexp.rl.evaluate": {"aslexp.envs.imitation": 19},
             "aslexp.envs.batched": {"aslexp.rl.evaluate": 118},
             "aslexp.tuning.worker": {"aslexp.runs.record": 59},
             "aslexp.runs.sweep_report": {"aslexp.tuning.study": 18},
             "aslexp.envs.imitation": {}, "aslexp.runs.record": {}, "aslexp.tuning.study": {}}
    assert cycles(graph) == [["aslexp.keypoints.registry", "aslexp.keypoints.source"]]
    assert sorted(cycles(room_graph(graph))) == [["envs", "rl"], ["runs", "tuning"]]
    assert [line.split(" imports ")[0] for line in upward_imports(graph)] == [
        "aslexp.envs.batched:118", "aslexp.rl.evaluate:19", "aslexp.tuning.worker:59"]


def test_reports_and_the_results_page_only_read_run_folders():
    """A report reads what its runs measured; nothing under reports/ or results/ builds an
    environment, an engine or a learner (what simulates lives in measure/ and runs with the job)."""
    simulating = ("envs", "sim", "rl", "measure", "control")
    found = [f"{module}:{line} imports {target}" for module, targets in import_graph().items()
             if module.startswith(("aslexp.reports", "aslexp.results")) for target, line in targets.items()
             if target.split(".")[1] in simulating]
    assert not found, "\n".join(found)


def _third_party_imports(name: str) -> list[str]:
    """``module:line`` of every import of the top-level package ``name`` under src/aslexp."""
    found = []
    for module, path in _modules().items():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
            targets = ([alias.name for alias in node.names] if isinstance(node, ast.Import)
                       else [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level else [])
            if any(target.split(".")[0] == name for target in targets):
                found.append(f"{module}:{node.lineno}")
    return found


def test_hydra_composes_at_the_edge_and_in_one_composer():
    """Hydra composes the jobs' configs (aslexp.jobs) and every group named below
    the edge (aslexp.compose, the one composer: no second reader of the YAML tree); the rest of the
    house takes plain dicts and reads them with aslexp.config_schema.read."""
    allowed = ("aslexp.jobs", "aslexp.compose")
    found = [where for where in _third_party_imports("hydra") if not where.startswith(allowed)]
    assert not found, "Hydra imported outside the jobs and aslexp.compose:\n" + "\n".join(found)
    assert not (PACKAGE / "envs" / "config.py").exists()


def test_matplotlib_is_imported_only_in_viz():
    """Every plot is drawn in aslexp.viz: the wings compute what a plot shows and hand it over, so a
    node without matplotlib runs every job and report that draws nothing."""
    found = [where for where in _third_party_imports("matplotlib") if not where.startswith("aslexp.viz")]
    assert not found, "matplotlib imported outside aslexp.viz:\n" + "\n".join(found)
