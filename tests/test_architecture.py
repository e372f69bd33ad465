"""The package's shape: module sizes by concept, import cycles, a light `import hydroarm` (the layer
contracts themselves are import-linter's, run by CI: `lint-imports`)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import grimp
import numpy as np
import pytest

import hydroarm

SOURCE = Path(hydroarm.__file__).parent
ARCHITECTURE = Path(__file__).resolve().parents[1] / "docs" / "architecture.md"

GUIDE_LINES = 500
"""A module of one concept usually fits in ~500 lines; past that, check that it holds one concept."""

CEILING_LINES = 800
"""No module above this: past ~800 lines a module holds more than one concept (or one concept
that has parts worth naming), and splitting it along that boundary is the way down."""

LONG_MODULES: dict[str, str] = {
    "model/arm/fast_jax.py": "the GPU path's control period as one file: scripts/gpu_plant.py --run loads it "
    "by file path on a machine with only JAX and NumPy, so its kernels (tree, water, CRBA, solve, RK4) "
    "cannot import one another from sibling modules",
    "envs/vector.py": "the multi-process vector env as one Gymnasium VectorEnv: its lanes' commands, "
    "errors, a dead worker, Ctrl-C and closing (the workers' side is envs/vector_lanes.py)",
    "sim/experiment.py": "one experiment as validated data and its one builder: ExperimentConfig (every "
    "section, its compact form for run ids, reading settings of any schema) and build_experiment "
    "(the migrations and the settings rules are sim/settings_schema.py and sim/settings_rules.py)",
}
"""The modules allowed above :data:`GUIDE_LINES`, each with the concept that justifies its size."""


def _module_sizes() -> dict[str, int]:
    sizes = {p.relative_to(SOURCE).as_posix(): len(p.read_text().splitlines()) for p in SOURCE.rglob("*.py")}
    assert sizes, "no modules found"
    return sizes


def test_modules_are_sized_by_concept():
    """Modules by concept, not by size (issue 20): ~500 lines is a guide, not a rule that splits
    one concept in two. A module may pass :data:`GUIDE_LINES` when it is listed in
    :data:`LONG_MODULES` with the concept that holds it together; none passes :data:`CEILING_LINES`.
    The list stays true: a listed module that shrank back under the guide leaves it."""
    sizes = _module_sizes()
    assert {name: n for name, n in sizes.items() if n > CEILING_LINES} == {}, f"over {CEILING_LINES} lines"
    unlisted = {name: n for name, n in sizes.items() if n > GUIDE_LINES and name not in LONG_MODULES}
    assert unlisted == {}, f"over {GUIDE_LINES} lines: split by concept or list it with its concept"
    stale = {name: sizes.get(name) for name in LONG_MODULES if sizes.get(name, 0) <= GUIDE_LINES}
    assert stale == {}, "listed in LONG_MODULES but missing or not above the guide"


def test_the_dry_model_does_not_import_the_true_plant():
    """The controllers' dry model (model.nominal) shares the integrator with the true plant, not
    the plant itself (issue 20): no import chain from one to the other."""
    graph = grimp.build_graph("hydroarm")
    assert not graph.chain_exists(importer="hydroarm.model.dynamics.nominal", imported="hydroarm.model.arm.plant")


def test_the_architecture_page_names_every_module_under_its_layer():
    """docs/architecture.md's module list is the package's: each subpackage's modules (and
    sub-subpackages) are named, in backticks, under its layer, and every lower-case name there
    is one of them (a moved, merged or renamed module shows here)."""
    section = ARCHITECTURE.read_text().split("## The modules, layer by layer", 1)[1].split("\n## ", 1)[0]
    bullets = re.findall(r"^- \*\*`hydroarm\.(\w+)`\*\*:(.*?)(?=^- |\Z)", section, re.M | re.S)
    named = {layer: set(re.findall(r"`([a-z_][a-z0-9_]*)`", text)) for layer, text in bullets}
    actual = {
        package.name: {
            p.stem if p.is_file() else p.name
            for p in package.iterdir()
            if not p.name.startswith("_")
            and ((p.is_file() and p.suffix == ".py") or (p.is_dir() and (p / "__init__.py").exists()))
        }
        for package in SOURCE.iterdir()
        if package.is_dir() and (package / "__init__.py").exists()
    }
    assert sorted(named) == sorted([*actual, "config"]), "one bullet per layer"
    for layer, modules in actual.items():
        assert modules - named[layer] == set(), f"hydroarm.{layer}: modules not named on the page"
        assert named[layer] - modules == set(), f"hydroarm.{layer}: names on the page that are no module"


def _strongly_connected(graph: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's algorithm: the components of more than one module (import cycles)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in graph.get(node, ()):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
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

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10_000))
    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def test_no_import_cycles():
    graph = grimp.build_graph("hydroarm")
    edges = {module: graph.find_modules_directly_imported_by(module) for module in graph.modules}
    assert _strongly_connected(edges) == []


def test_cycle_finder_finds_a_cycle():
    assert _strongly_connected({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


@pytest.mark.subprocess
def test_import_hydroarm_is_light():
    code = (
        "import sys, hydroarm; heavy = [m for m in sys.modules if m.startswith(('hydroarm.', 'gymnasium', "
        "'pinocchio', 'numba', 'matplotlib'))]; print(heavy); assert not heavy"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stdout + result.stderr


@pytest.mark.subprocess
def test_the_simulation_core_loads_no_study_env_cli_or_plotting():
    """A run through the public API (hydroarm.run_experiment: the sim layer) needs no study,
    env or CLI module, nor matplotlib or gymnasium (the layer rule, checked where it matters)."""
    code = (
        "import sys, hydroarm; hydroarm.ExperimentConfig; hydroarm.build_experiment; hydroarm.Trajectory; "
        "import hydroarm.sim.experiment, hydroarm.sim.runner; "
        "heavy = [m for m in sys.modules if m.startswith(('hydroarm.studies', 'hydroarm.envs', 'hydroarm.cli', "
        "'gymnasium', 'matplotlib'))]; print(heavy); assert not heavy"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr


def test_public_api_names_resolve():
    for name in hydroarm.__all__:
        assert getattr(hydroarm, name) is not None, name
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        hydroarm.nope  # noqa: B018


def test_every_true_plant_follows_the_plant_protocol():
    """The fixed-base arm, the vehicle with its arm and its compiled fast path are one protocol
    (hydroarm.sim.plant_protocol.Plant): the one runner runs each of them."""
    from hydroarm.model.arm.loading import load_arm
    from hydroarm.model.arm.plant import UnderwaterPlant
    from hydroarm.model.vehicle.fast import FastUVMSPlant
    from hydroarm.model.vehicle.plant import UVMSPlant
    from hydroarm.model.vehicle.system import build_uvms
    from hydroarm.sim.plant_protocol import Plant

    uvms = build_uvms("bluerov2-heavy", "mount")
    for plant in (UnderwaterPlant(load_arm("paper")), UVMSPlant(uvms), FastUVMSPlant(uvms)):
        assert isinstance(plant, Plant), type(plant).__name__
        x = plant.initial_state(uvms.neutral()) if hasattr(plant, "initial_state") else np.zeros(plant.state_size)
        assert x.shape == (plant.state_size,) and plant.joint_state(x).shape == (2 * plant.n,)
        x_next, info = plant.step(0.0, x, np.zeros(plant.n_inputs), 0.01)
        assert x_next.shape == x.shape and info.disturbance.shape == (plant.n,)


def _resolve(dotted: str) -> object:
    """The module, class, function or attribute a dotted name names (ImportError/AttributeError if none)."""
    import importlib

    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            target = importlib.import_module(".".join(parts[:cut]))
        except ModuleNotFoundError:
            continue
        for name in parts[cut:]:
            target = getattr(target, name)
        return target
    raise ImportError(dotted)


def test_where_to_add_names_what_the_code_has():
    """docs/architecture.md's "Where to add..." is checked against the code: every dotted name
    there (a module, a class, a function, a registry) resolves, every test file and source folder
    it points to exists, and the protocol members it lists for a plant, a sensor and a drive block
    are the code's."""
    section = ARCHITECTURE.read_text().split("## Where to add...", 1)[1].split("\n## ", 1)[0]
    names = set(re.findall(r"`(hydroarm(?:\.\w+)+)`", section))
    assert len(names) > 15
    for name in sorted(names):
        _resolve(name)
    root = ARCHITECTURE.parents[1]
    for test_file in set(re.findall(r"tests/test_\w+\.py", section)):
        assert (root / test_file).is_file(), test_file
    for folder in set(re.findall(r"`(hydroarm/[\w/]+/)`", section)):
        assert (root / "src" / folder).is_dir(), folder
    from hydroarm.model.real_loop.sensing import Actuator, Sensor
    from hydroarm.model.vehicle.system import StateLayout
    from hydroarm.sim.plant_protocol import Plant

    plant_entry = section.split("- **A plant.**", 1)[1].split("\n- **", 1)[0]
    members = {*Plant.__annotations__, *(m for m in vars(Plant) if not m.startswith("_"))}
    for member in ("n", "n_inputs", "state_size", "step", "measure", "new_sensor", "new_actuator"):
        assert f"`{member}`" in plant_entry and member in members, member
    for part in ("base_pose", "arm_q", "base_velocity", "arm_v", "thrust"):
        assert f"`{part}`" in plant_entry and part in StateLayout.__dataclass_fields__, part
    assert callable(Sensor.sample) and callable(Actuator.apply)
