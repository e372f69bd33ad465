"""The package's shape: module sizes, import cycles, a light `import hydroarm` (the layer
contracts themselves are import-linter's, run by CI: `lint-imports`)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import grimp
import numpy as np
import pytest

import hydroarm

SOURCE = Path(hydroarm.__file__).parent
MAX_LINES = 500


def test_no_source_module_is_over_500_lines():
    sizes = {str(p.relative_to(SOURCE)): len(p.read_text().splitlines()) for p in SOURCE.rglob("*.py")}
    assert sizes, "no modules found"
    assert {name: n for name, n in sizes.items() if n > MAX_LINES} == {}


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
    (hydroarm.sim.plant.Plant): the one runner runs each of them."""
    from hydroarm.model.loading import load_arm
    from hydroarm.model.plant import UnderwaterPlant
    from hydroarm.model.uvms import build_uvms
    from hydroarm.model.uvms_fast import FastUVMSPlant
    from hydroarm.model.uvms_plant import UVMSPlant
    from hydroarm.sim.plant import Plant

    uvms = build_uvms("bluerov2-heavy", "mount")
    for plant in (UnderwaterPlant(load_arm("paper")), UVMSPlant(uvms), FastUVMSPlant(uvms)):
        assert isinstance(plant, Plant), type(plant).__name__
        x = plant.initial_state(uvms.neutral()) if hasattr(plant, "initial_state") else np.zeros(plant.state_size)
        assert x.shape == (plant.state_size,) and plant.joint_state(x).shape == (2 * plant.n,)
        x_next, info = plant.step(0.0, x, np.zeros(plant.n_inputs), 0.01)
        assert x_next.shape == x.shape and info.disturbance.shape == (plant.n,)
