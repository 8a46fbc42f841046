import warnings, time, sys, numpy as np
warnings.simplefilter("ignore")
from common import target
from modalctl.decompose import decompose
from modalctl.hil.scenario import Perturbation, perturb
from modalctl.planner import plan
from modalctl.scenes import load_scene
from modalctl.loop import closed_shot, loop_parts
from modalctl.hil.board import HILBoard
import modalctl.hil.board as B, modalctl.hil.lifted as L, modalctl.propagate as P
rate = float(sys.argv[1])
model = load_scene("thesis-al-cc", 211)
shape = target(model, "sinc", width="18mm", center="24mm")
shot = plan(decompose(model, shape, "auto"), 0.025, sample_rate=500e3)
truth = perturb(model, Perturbation(drift=0.01, damping_error=0.2))
sigma = shot.focus_peak / 100
parts = loop_parts(shot, rate, sigma, 2.0, 0, "pi")
acc = {}
def wrap(obj, name, key):
    f = getattr(obj, name)
    def g(*a, **k):
        t = time.perf_counter(); r = f(*a, **k); acc.setdefault(key, []).append(time.perf_counter() - t); return r
    setattr(obj, name, g)
wrap(HILBoard, "configure", "configure"); wrap(HILBoard, "start", "start"); wrap(HILBoard, "_play_back", "play_back")
wrap(L.PeriodMap, "__init__", "map init"); wrap(P.Plant, "simulate", "plant.simulate"); wrap(L, "open_envelopes", "open_envelopes")
wrap(B, "open_envelopes", "open_envelopes(B)"); wrap(HILBoard, "_draw_noise", "draw_noise"); wrap(B.BlockLockIn, "__init__", "lockin init")
wrap(B.BlockPlant, "__init__", "blockplant init")
def one(seed):
    board = HILBoard(truth, 500e3, noise=sigma, seed=seed)
    t0 = time.perf_counter()
    res = closed_shot(shot, board, parts, True, None, None, 0, 1.0, None, None)
    board.play_out(); board.velocity
    return time.perf_counter() - t0, res.loop_seconds
for s in range(3): one(s)
acc.clear()
rows = [one(s) for s in range(8)]
print(rate, "whole ms", round(np.median([r[0] for r in rows]) * 1e3, 2), "loop", round(np.median([r[1] for r in rows]) * 1e3, 2))
for k, v in acc.items(): print(f"  {k:20s} median ms {np.median(v) * 1e3:7.2f}  calls/shot {len(v) / 8:g}")
