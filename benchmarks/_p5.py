import warnings, time, numpy as np
warnings.simplefilter("ignore")
from common import target
from modalctl.decompose import decompose
from modalctl.hil.scenario import Perturbation, perturb
from modalctl.planner import plan
from modalctl.scenes import load_scene
from modalctl.loop import closed_shot, loop_parts
from modalctl.hil.board import HILBoard
import modalctl.hil.board as B
model = load_scene("thesis-al-cc", 211)
shape = target(model, "sinc", width="18mm", center="24mm")
shot = plan(decompose(model, shape, "auto"), 0.025, sample_rate=500e3)
truth = perturb(model, Perturbation(drift=0.01, damping_error=0.2))
sigma = shot.focus_peak / 100
parts = loop_parts(shot, 10e3, sigma, 2.0, 0, "pi")
acc = {"read": [], "write": [], "play_lifted": [], "step_commands": []}
def wrap(cls, name, key):
    f = getattr(cls, name)
    def g(*a, **k):
        t = time.perf_counter(); r = f(*a, **k); acc[key].append(time.perf_counter() - t); return r
    setattr(cls, name, g)
wrap(HILBoard, "read", "read"); wrap(HILBoard, "write", "write"); wrap(HILBoard, "_play_lifted", "play_lifted")
from modalctl.hil.lifted import PeriodMap
wrap(PeriodMap, "step_commands", "step_commands")
phases = {}
def one(seed):
    board = HILBoard(truth, 500e3, noise=sigma, seed=seed)
    t0 = time.perf_counter()
    res = closed_shot(shot, board, parts, True, None, None, 0, 1.0, None, None)
    t1 = time.perf_counter()
    board.play_out(); board.velocity
    t2 = time.perf_counter()
    return t2 - t0, res.configure_seconds, res.loop_seconds, t2 - t1
for s in range(3): one(s)
for k in acc: acc[k].clear()
rows = [one(s) for s in range(8)]
print("whole, configure, loop, records (ms):", np.round(np.median(rows, axis=0) * 1e3, 2))
for k, v in acc.items(): print(k, "median us", round(np.median(v) * 1e6, 1), "n/shot", len(v) // 8)
