"""The front door: modalctl.api, plugins handed to run() as objects, and the third-party planner and
controller that docs/plugins.md shows, run as written there."""

import re
import types
from pathlib import Path

import numpy as np
import pluggy
import pytest

from modalctl import api as mc
from modalctl.plugin import spec as hookspecs
from modalctl.plugin.manager import ENTRY_POINT_GROUP

DOCS = Path(__file__).resolve().parents[1] / "docs" / "plugins.md"


def _example(title: str) -> tuple[types.ModuleType, int]:
    """The module the first python block under ``## title`` in docs/plugins.md defines, and its lines."""
    section = DOCS.read_text().split(f"## {title}\n", 1)[1]
    code = re.search(r"```python\n(.*?)```", section, re.DOTALL).group(1)
    module = types.ModuleType(title.replace(" ", "_").replace(",", ""))
    exec(compile(code, f"docs/plugins.md ({title})", "exec"), module.__dict__)
    return module, code.count("\n")


@pytest.fixture(scope="module")
def examples():
    planner, planner_lines = _example("A planner, start to finish")
    controller, controller_lines = _example("A controller, start to finish")
    return types.SimpleNamespace(planner=planner, controller=controller,
                                 lines=(planner_lines, controller_lines))


@pytest.fixture(scope="module")
def scene():
    model = mc.load_scene("thesis-al-cc")
    return model, mc.make_shape("sinc", model, width="18mm", center="24mm")


def _shot(scene, plan_options, loop=None, manager=None, **truth):
    model, sinc = scene
    with mc.connect("sim://", model=model, target=sinc, **truth) as device:
        return mc.run(model, sinc, device, mc.RunOptions(25e-3, plan_options, loop), manager=manager)


def test_the_examples_are_complete_and_short(examples):
    assert all(lines < 60 for lines in examples.lines), examples.lines
    assert issubclass(examples.planner.SlowEnvelopes, mc.Planner)
    assert issubclass(examples.controller.ProportionalLoops, mc.ControllerFactory)


def test_a_planner_and_a_controller_passed_as_objects_are_used(examples, scene):
    calls = []

    class Counted(examples.planner.SlowEnvelopes):
        def plan(self, *args, **kwargs):
            calls.append("plan")
            return super().plan(*args, **kwargs)

    class CountedLoops(examples.controller.ProportionalLoops):
        def create(self, plant, **options):
            calls.append("create")
            return super().create(plant, **options)

    plan_options = mc.PlanOptions(planner=Counted(), margin=None, modes=9)
    shot = _shot(scene, plan_options, mc.LoopOptions(controller=CountedLoops()), drift=0.01)
    assert calls == ["plan", "create"]
    assert shot.metrics.planner == "slow-envelopes" and shot.loop.controller == "proportional"
    assert shot.loop.crossover_hz == pytest.approx([20e3 / 40] * 9)  # the example's design, not the PI's
    np.testing.assert_allclose(shot.plan.kappa, 0.5)


def test_a_third_party_planner_with_only_the_contract_runs_end_to_end(examples, scene):
    """Its plan's report is empty: run() names it, times it and measures the whole-model margin,
    which must equal what the first-party envelope planner predicts for the same drive."""
    plan_options = mc.PlanOptions(planner=examples.planner.SlowEnvelopes(kappa=0.5), margin=None, modes=9)
    shot = _shot(scene, plan_options)
    assert shot.plan.report.whole_model_margin_ratio is None and shot.plan.report.plan_seconds > 0
    same = mc.plan_shot(*scene, 25e-3, mc.PlanOptions(planner="envelope", margin=None, modes=9, kappa=0.5,
                                                       compensate=False))[1]
    np.testing.assert_allclose(shot.plan.voltages(), same.voltages(), rtol=1e-12, atol=1e-12)
    assert shot.metrics.whole_model_margin_ratio == pytest.approx(same.report.whole_model_margin_ratio, rel=1e-9)
    assert shot.metrics.tau > 0.97  # a perfect model, open loop: the thesis's 0.99 on the 18 mm sinc
    with pytest.raises(mc.PlanError, match="above the 1 V limit"):
        mc.plan_shot(*scene, 25e-3, plan_options.but(voltage_limit=1.0))


def test_the_third_party_controller_recovers_part_of_what_drift_spoils(examples, scene):
    plan_options = mc.PlanOptions(planner=examples.planner.SlowEnvelopes(), margin=None, modes=9)
    open_loop = _shot(scene, plan_options, drift=0.01)
    closed = _shot(scene, plan_options, mc.LoopOptions(controller=examples.controller.ProportionalLoops()),
                   drift=0.01)
    assert closed.metrics.tau > open_loop.metrics.tau + 0.05, (open_loop.metrics.tau, closed.metrics.tau)


def test_registered_plugins_are_reached_by_name_through_the_manager_handed_to_run(examples, scene):
    manager = pluggy.PluginManager(ENTRY_POINT_GROUP)
    manager.add_hookspecs(hookspecs)
    manager.register(examples.planner)
    manager.register(examples.controller)
    plan_options = mc.PlanOptions(planner="slow-envelopes", margin=None, modes=9)
    shot = _shot(scene, plan_options, mc.LoopOptions(controller="proportional"), manager=manager)
    assert shot.metrics.planner == "slow-envelopes" and shot.loop.controller == "proportional"
    with pytest.raises(mc.PluginError, match="installed: slow-envelopes"):
        _shot(scene, plan_options.but(planner="convex"), manager=manager)


def test_every_name_the_front_door_exports_exists():
    missing = [name for name in mc.__all__ if not hasattr(mc, name)]
    assert not missing


def test_python_dash_m_modalctl_is_the_command_line():
    """``python -m modalctl`` runs the same commands as the script (profilers start it that way)."""
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-m", "modalctl", "scenes"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and "panel-rounded" in done.stdout
