"""``modalctl run``: plan a focus, play it on a device (``sim://`` by default), measure it, and write
the run's report (metrics.json, fields.npz, the pictures) into ``--out``."""

from __future__ import annotations

import json
import math
import signal
import sys
from pathlib import Path

from modalctl.options import BOARD_CONTROLLER, HOST_CONTROLLER, KAPPA_MAX, KAPPA_MIN, LEARN_FROM, ROBUST_DRIFT_MAX, \
    SLEW_MIN, VOLTAGE_MIN, LoopOptions, PlanOptions
from modalctl.units import number_type, quantity_type

from .common import DEVICE, UNREACHABLE, add_target, identity, identity_defaults, interruptible, jsonable, \
    model_and_shape, open_device, out_dir, progress_bars, stage, write_json

NAME, HELP = "run", "plan a focus, play it on a device (default sim://) and measure it"
PLAN, LOOP = PlanOptions(), LoopOptions()  # the defaults the options below show and use


def add_parser(sub):
    return sub.add_command(NAME, HELP, add_arguments, run)


def add_arguments(p) -> None:
    from modalctl.io.device import add_transport_options

    add_target(p)
    p.add_argument("--focus-time", required=True, type=quantity_type("s", "focus-time", low=0), help="T_F, e.g. 25ms")
    _add_plan_arguments(p)
    p.add_argument("--transport", default="sim://", help="device URL (default sim://)")
    _add_loop_arguments(p.add_argument_group("closed loop"))
    p.set_defaults(transports=add_transport_options(p))
    p.add_argument("--out", required=True, type=out_dir,
                   help="directory for metrics.json, fields.npz and the pictures")
    p.add_argument("--force", action="store_true", help="replace another run's results in --out")
    p.add_argument("--no-plots", action="store_true")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _add_plan_arguments(p) -> None:
    p.add_argument("--planner", default=PLAN.planner,
                   help="planner plugin; convex: the least-energy drive that holds the margin on every sample of "
                        f"the whole model (a QP); envelope: the thesis's exponential envelopes ({PLAN.planner})")
    p.add_argument("--margin", type=_margin, default=PLAN.margin,
                   help="transient margin off target, before and after T_F, as a share of the focus peak, "
                        f"e.g. 0.5 or 50%%, or none ({_margin_words(PLAN.margin)})")
    p.add_argument("--robust-drift", type=quantity_type("1", "robust-drift", low=0, high=ROBUST_DRIFT_MAX,
                                                        low_open=False),
                   default=PLAN.robust_drift,
                   help="convex planner: hold the margin on every truth whose resonances lie within this band "
                        "of the model's, e.g. 1%% (0)")
    p.add_argument("--voltage-limit", type=voltage_limit,
                   help="largest drive voltage, e.g. 100V, or none; a plan above it is refused (exit 1). Default: "
                        "the model's actuators' safe voltage (its meta's voltage_limit_v: 70 V for the scenes' "
                        "0.2 mm PZT-5A patches), none when the model does not say")
    p.add_argument("--plan-time", type=plan_time,
                   help="convex planner: the time a margin program may take, e.g. 300s, or none (until it is done); "
                        "past it the plan is refused, saying where it stopped: a plan found within it does not "
                        f"depend on the machine's speed ({PLAN.convex.program_seconds:g}s)")
    p.add_argument("--slew-limit", type=quantity_type("V/s", "slew-limit", low=SLEW_MIN, low_open=False),
                   help="largest output slope, e.g. 2e6V/s: planned for by the convex planner, and the "
                        "closed loop's feedback clipped to it")
    p.add_argument("--margin-on", choices=("whole", "kept"), default=PLAN.margin_on,
                   help="where --margin must hold: whole (the field the voltages drive on every mode of the "
                        "model; they are corrected near the focus until it does, up to a minute) or kept (the "
                        "kept modes' references, the thesis's criterion)")
    p.add_argument("--kappa", type=number_type(float, "kappa", low=KAPPA_MIN, high=KAPPA_MAX, low_open=False),
                   default=PLAN.kappa,
                   help=f"envelope rate without --margin ({PLAN.kappa:g})")
    p.add_argument("--no-brake", action="store_true", help="optimizer: free decay after the focus only")
    p.add_argument("--after", type=quantity_type("s", "after", low=0), default=PLAN.after,
                   help=f"post-transient window recorded and checked ({PLAN.after * 1e3:g}ms)")
    p.add_argument("--sample-rate", type=quantity_type("Hz", "sample-rate", low=0), default=PLAN.sample_rate,
                   help=f"DAC rate ({PLAN.sample_rate / 1e6:g}MHz)")


def _add_loop_arguments(loop) -> None:
    loop.add_argument("--loop", choices=("open", "closed", "board"), default="open",
                      help="open: feed-forward only (the thesis); closed: per-mode feedback on top (the touch "
                           "controller: PI plus what a finger and a drift take), one exchange with the board per "
                           "period (at most the rate the link carries); board: PI loops and their reference tables "
                           "loaded into the board, which closes them itself (no link budget; modes x periods within "
                           "its memory)")
    loop.add_argument("--control-rate", type=quantity_type("Hz", "control-rate", low=0), default=LOOP.control_rate,
                      help=f"loop rate, a divisor of the sample rate ({LOOP.control_rate / 1e3:g}kHz)")
    loop.add_argument("--authority", type=number_type(float, "authority", low=0, low_open=False),
                      default=LOOP.authority,
                      help=f"largest feedback per mode, as a fraction of its planned drive ({LOOP.authority:g})")
    loop.add_argument("--latency", type=number_type(int, "latency", low=0, high=1000, low_open=False),
                      default=LOOP.latency, help=f"extra periods the board takes to use a command ({LOOP.latency})")
    loop.add_argument("--controller", default=LOOP.controller,
                      help=f"per-mode controller plugin: pi, lqg, touch (pi plus the force a finger and a drift "
                           f"take, estimated during the shot), cluster (one LQ law per cluster of close modes) or "
                           f"touch+cluster (touch over the cluster laws, pi on the other modes) ({HOST_CONTROLLER}; "
                           f"{BOARD_CONTROLLER} on a board)")
    loop.add_argument("--touch-at", type=quantity_type("m", "touch-at", point=True), metavar="POINT",
                      help="touch and touch+cluster: where a touch sensor says the finger rests, e.g. 0mm (default: "
                           "the controller finds it)")
    loop.add_argument("--watchdog", type=number_type(int, "watchdog", low=1, high=10**6, low_open=False),
                      default=LOOP.watchdog,
                      help=f"periods without a measurement before the supervisor stops the shot ({LOOP.watchdog})")
    loop.add_argument("--learn", nargs="?", const="record", choices=LEARN_FROM,
                      help="a first shot teaches the model: from its record (record, the default: played open "
                           "loop, every resonance and damping fitted to it) or from a pole tracker during it "
                           "(tracker: closed loop); planned without the loop's drift band; "
                           "the shot planned again on the updated model is the one reported")


_VOLTS = quantity_type("V", "voltage-limit", low=VOLTAGE_MIN, low_open=False)


def _or_none(quantity):
    """An option's type: what ``quantity`` (a :func:`~modalctl.units.quantity_type`) reads, or ``none``."""
    def read(text: str):
        return "none" if text.strip().lower() == "none" else quantity(text)

    read.bounds, read.__name__ = quantity.bounds, quantity.__name__  # its range, for the property suite
    return read


#: ``--voltage-limit``: a voltage (V) of at least VOLTAGE_MIN, or ``none`` (no limit but the device's rails)
voltage_limit = _or_none(_VOLTS)
#: ``--plan-time``: the seconds a margin program may take (zero or more), or ``none`` (until it is done)
plan_time = _or_none(quantity_type("s", "plan-time", low=0, low_open=False))


def _planned_voltage(args, model, options):
    """``options`` with the plan's voltage limit: ``--voltage-limit``, or none, or by default the
    model's actuators' safe voltage (:attr:`~modalctl.model.modes.ModalModel.voltage_limit`)."""
    if args.voltage_limit is not None or model.voltage_limit is None:
        return options
    return options.but(plan=options.plan.but(voltage_limit=model.voltage_limit))


def _voltage_said(args, model) -> dict:
    """The plan's voltage limit (V, or None) and where it came from, for metrics.json."""
    if args.voltage_limit == "none" or (args.voltage_limit is None and model.voltage_limit is None):
        return {"voltage_limit_v": None, "voltage_limit_source": "none"}
    if args.voltage_limit is not None:
        return {"voltage_limit_v": args.voltage_limit, "voltage_limit_source": "--voltage-limit"}
    return {"voltage_limit_v": model.voltage_limit,
            "voltage_limit_source": model.meta.get("voltage_limit_source", "the model's meta")}


def _said_why(args, model, refused, options):
    """A refusal says what the user may change: under the default voltage limit, where the limit
    comes from (the model's actuators); for a closed loop planned over the loop's drift band, that
    ``--learn`` plans without it."""
    from modalctl.plan.planner import PlanError

    hints = []
    if args.voltage_limit is None and model.voltage_limit is not None:
        source = model.meta.get("voltage_limit_source", "its meta's voltage_limit_v")
        hints.append(f"the {model.voltage_limit:g} V limit is the model's actuators' safe voltage: {source}; "
                     "--voltage-limit sets another")
    band = options.planned.robust_drift
    if band > options.plan.robust_drift:  # the closed loop's band, added to the plan (RunOptions.planned)
        hints.append(f"a closed loop's plan holds the margin over +-{band:.0%} of resonance drift; --learn plans "
                     "it on the model a first shot measures, without that band")
    if not hints:
        return refused
    return PlanError(f"{refused} ({'; '.join(hints)})", refused.needed, refused.limit, refused.certificate)


def _margin(text: str) -> float | None:
    """``--margin``: a share of the focus peak in (0, 1], or ``none``."""
    if text.strip().lower() == "none":
        return None
    return quantity_type("1", "margin", low=0, high=1)(text)


def _margin_words(margin: float | None) -> str:
    return "none" if margin is None else f"{margin:g}"


def _run_options(args, out: Path):
    """The typed options of ``modalctl run``."""
    from modalctl.model.shape import ParamError
    from modalctl.options import RunOptions
    from modalctl.plugin.manager import get_planner

    unused = [why for given, applies, why in _applying(args) if given and not applies]
    if unused:
        raise ParamError("; ".join(unused))
    get_planner(args.planner)  # an unknown planner is bad input, refused before the device opens
    plan = PlanOptions(planner=args.planner, modes=args.modes, tau_min=args.tau_target or PLAN.tau_min,
                       margin=args.margin, margin_on=args.margin_on,
                       voltage_limit=None if args.voltage_limit == "none" else args.voltage_limit,
                       slew_limit=args.slew_limit, robust_drift=args.robust_drift, kappa=args.kappa,
                       brake=not args.no_brake, after=args.after, sample_rate=args.sample_rate)
    if args.plan_time is not None:
        plan = plan.but(convex=plan.convex.but(program_seconds=None if args.plan_time == "none" else args.plan_time))
    loop = None if args.loop == "open" else LoopOptions(
        control_rate=args.control_rate, controller=args.controller, on_board=args.loop == "board",
        authority=args.authority, latency=args.latency, slew_limit=args.slew_limit, watchdog=args.watchdog,
        touch_at=args.touch_at)
    return RunOptions(args.focus_time, plan, loop, args.learn, out / "log" if loop else None, progress_bars(args))


def _senses_touch(controller: str) -> bool:
    """Whether the controller plugin named estimates a touch (an unknown name: True here, so that it is refused
    where the loops are made, with the installed names, not as a misplaced --touch-at)."""
    from modalctl.plugin.manager import PluginError, pick

    try:
        return bool(getattr(pick("controller", controller), "senses_touch", False))
    except PluginError:
        return True


def _applying(args) -> list[tuple[bool, bool, str]]:
    """Each option the other choices can make meaningless: (given, applies, why not), so that an
    option is refused where it would be ignored."""
    closed, convex = args.loop != "open", args.planner == "convex"
    return [
        (bool(args.learn), closed, "--learn needs a closed loop (--loop closed or board)"),
        (args.touch_at is not None, args.loop == "closed" and _senses_touch(args.controller or HOST_CONTROLLER),
         "--touch-at tells a controller that estimates the touch (touch, touch+cluster) where the finger rests: it "
         "needs --loop closed and one of them"),
        (args.robust_drift > 0, convex and args.margin is not None,
         "--robust-drift holds the convex planner's margin on drifted truths: it needs --planner convex and a "
         "--margin (not none)"),
        (args.slew_limit is not None, convex,
         "--slew-limit is planned for by the convex planner only: the envelope planner's drive would exceed it"),
        (args.plan_time is not None, convex, "--plan-time bounds the convex planner's margin program only"),
    ]


def run(args) -> int:
    """A shot; a signal (SIGINT, SIGTERM, SIGHUP) ends it as a fault does, with its own exit code
    (:class:`~modalctl.cli.common.Interrupted`)."""
    with interruptible():
        return _run(args)


def _run(args) -> int:
    import warnings

    from modalctl.io.device import DeviceError
    from modalctl.loops.realtime import keep_memory
    from modalctl.outdir import claim
    from modalctl.plan.dispatch import DecouplingWarning
    from modalctl.plan.planner import PlanError
    from modalctl.run import run as play

    keep_memory()  # shots reuse their memory instead of faulting on fresh pages each time
    warnings.simplefilter("ignore", DecouplingWarning)  # printed below from the metrics
    out = Path(args.out)
    options = _run_options(args, out)
    import time

    started = time.perf_counter()
    stage(args, f"the model ({args.scene or args.model}) and the shape ({args.shape})")
    model, shape = model_and_shape(args)
    if args.touch_at is not None:  # on the structure, checked before the model grows and the plan is made
        from modalctl.model.touch import touch_at

        touch_at(model, args.touch_at)
    options = _planned_voltage(args, model, options)
    loaded = time.perf_counter()
    model, growth = _grown(args, model, shape, options)
    stages = {"model_s": loaded - started, "growth_s": time.perf_counter() - loaded}
    with open_device(args, model, shape) as device:  # its options checked before the folder is made
        claim(out, "run", identity(args), args.force, identity_defaults("run"))
        stage(args, f"the shot: planned ({options.plan.planner} planner) and played on {device.url}"
              + (f", {args.loop} loop" if options.closed else ""))
        try:
            shot = play(model, shape, device, options)
        except PlanError as refused:  # a result: why, on disk beside where the report would be
            refused = _said_why(args, model, refused, options)
            write_json(out / "refusal.json", {"refused": str(refused), "needed": refused.needed,
                                              "limit": refused.limit, "certificate": refused.certificate,
                                              "planner": options.plan.planner,
                                              "voltage_limit": options.plan.voltage_limit})
            raise refused from None
        except DeviceError as fault:
            _halted(out, device, fault)
            raise
        except KeyboardInterrupt as stopped:  # a signal: the loop ramped its outputs down; every board stopped here
            _halted(out, device, stopped, getattr(stopped, "code", 128 + 2))
            raise
        return _report(args, model, shot, device, out, growth, stages)


def _grown(args, model, shape, options):
    """The model grown until its modes draw the shape (a finite-element plate's; see
    :mod:`modalctl.plan.growth`), and how, or the model and None."""
    from modalctl.plan.growth import model_for

    say = None if args.quiet or args.json else (lambda line: print(line, flush=True))
    return model_for(model, shape, options.plan, say)


def _halted(out: Path, device, fault: BaseException, code: int = DEVICE) -> None:
    """After a device fault or a signal: every output commanded to zero (best effort), and what
    happened in ``out/metrics.json`` beside the loop's log, so the run's folder says why it has no
    field (``interrupted``: the signal's name, when one stopped it)."""
    could_not = device.halt()
    log = out / "log.json"
    outputs = "commanded to zero" if could_not is None else f"not confirmed at zero: {could_not}"
    metrics = {"fault": str(fault) or "interrupted by SIGINT", "exit_code": code, "device": device.url,
               "device_info": device.info, "outputs": outputs, "log": str(log) if log.exists() else None,
               "out": str(out)}
    if code != DEVICE:
        metrics["interrupted"] = signal.Signals(code - 128).name
        print(f"modalctl run: {metrics['fault']}: outputs {outputs}; {out}/metrics.json"
              + (f", log in {out}/log.json + log.bin" if log.exists() else ""), file=sys.stderr)
    write_json(out / "metrics.json", metrics)


def _report(args, model, shot, device, out, growth=None, stages=None) -> int:
    """metrics.json, fields.npz and the pictures of a run; the summary on stdout. ``stages``: the
    seconds the command spent before the shot (its model, its growth), written with the writing's."""
    import functools
    import time

    from modalctl.forked import beside
    from modalctl.outdir import record

    started = time.perf_counter()
    stage(args, f"the report into {out}/")
    metrics = {**shot.to_dict(), "scene": model.meta.get("name", args.model), "shape": args.shape,
               "params": dict(args.param), "truth": device.info.get("truth", device.url), "out": str(out),
               "model": {"modes": model.n_modes, "band_hz": float(model.frequencies.max()),
                         "grown": None if growth is None else growth.to_dict()}, **_voltage_said(args, model)}
    pictures = [] if args.no_plots else [beside(functools.partial(_draw, shot, out, time.perf_counter(), first))
                                         for first in (True, False)]
    try:
        _write_fields(model, shot, out, device)
    except BaseException:
        for child in pictures:
            child.stop()
        raise
    written = time.perf_counter()
    drawn = None
    if pictures:
        drawn = _pictures_drawn(pictures, metrics, out)
        record(out, [Path(picture).name for picture in metrics.get("pictures", {}).values()]
               + (["pictures-error.txt"] if "pictures_error" in metrics else []))
    metrics["stages_s"] = {**(stages or {}), "write_fields_s": written - started,
                           **({} if drawn is None else {"pictures_s": drawn,
                                                        "pictures_wait_s": time.perf_counter() - written})}
    unmeasured = [name for name in MEASURES if not math.isfinite(metrics[name])]
    if unmeasured:  # a field zero everywhere (a drive the amplifier did not pass): written, and not a success
        said = ", ".join(f"{n} ({metrics[n]})" for n in unmeasured)
        metrics.update(error=f"the shot's {said} {'is' if len(unmeasured) == 1 else 'are'} not finite: the field "
                             f"measured is zero or without a focus; the record is in {out}/",
                       code=UNREACHABLE, command="run")  # as a refusal's JSON says it (docs/errors.md)
        print(f"modalctl run: {metrics['error']}", file=sys.stderr)
    write_json(out / "metrics.json", metrics)
    fault = metrics.get("loop", {}).get("fault")
    if fault:  # the supervisor stopped the shot: the report is written, the run did not succeed
        print(f"modalctl run: the supervisor stopped the shot: {fault}; outputs ramped to zero, "
              f"log in {out}/log.json + log.bin", file=sys.stderr)
    code = DEVICE if fault else UNREACHABLE if unmeasured else 0
    if args.json:
        print(json.dumps(metrics, default=jsonable))
        return code
    _print_shot(args, metrics, shot.plan.report)
    _print_loop(metrics, shot, out)
    print(f"report: {out}/ (metrics.json, fields.npz" + (", pictures)" if "pictures" in metrics else ")"))
    return code


#: The shot's measures that a run with any result at all makes finite (docs/errors.md: exit 1 when not)
MEASURES = ("tau", "tau_norm", "nrmse", "margin_ratio")


#: The run's pictures, drawn by two forked children at once: these, and every other (on a plate each takes about half)
FIRST_PICTURES = ("spacetime", "voltages")


def _pictures_drawn(pictures: list, metrics: dict, out: Path) -> float | None:
    """The pictures the :func:`modalctl.forked.beside` children of :func:`_draw` made, into
    ``metrics["pictures"]``, and the seconds the last took; a drawing that failed (the shot, its
    metrics, its fields and the other pictures are not lost for it) is said on stderr, its
    traceback in ``DIR/pictures-error.txt`` and its last line in ``metrics["pictures_error"]``: None."""
    answers = []
    try:
        for child in pictures:
            try:
                answers.append(child.result())
            except RuntimeError as ended:  # the child ended without an answer
                answers.append({"error": str(ended)})
    except BaseException:  # interrupted while waiting: no child drawing on behind the run's back
        for child in pictures:
            child.stop()
        raise
    drawn = {k: v for answer in answers for k, v in answer.get("pictures", {}).items()}
    if drawn:
        metrics["pictures"] = drawn
    failed = [answer["error"] for answer in answers if "error" in answer]
    if not failed:
        return max(answer["seconds"] for answer in answers)
    from modalctl.outdir import atomic

    text = "\n".join(f"drawing the run's pictures failed: {error}" for error in failed)  # every child's
    with atomic(out / "pictures-error.txt") as path:  # never through a link planted in the folder
        path.write_text(text + "\n")
    last = [line for line in text.splitlines() if line.strip()][-1]
    metrics["pictures_error"] = last
    print(f"modalctl run: warning: the pictures could not be drawn ({last}); the shot's metrics and "
          f"fields are written; the traceback is in {out}/pictures-error.txt", file=sys.stderr)
    return None


def _draw(shot, out: Path, started: float, first: bool) -> dict:
    """The pictures of :data:`FIRST_PICTURES` (``first``) or every other (:func:`modalctl.report.write_run_report`)
    and the seconds since ``started``, or the traceback of what stopped them: drawn in a forked child while
    the run writes its fields (it shares the shot without a copy and imports matplotlib itself)."""
    import gc
    import time
    import traceback

    gc.disable()  # in a forked child its collections walked the parent's objects: a tenth of the drawing
    try:
        from modalctl.report import write_run_report

        drawn = write_run_report(shot, out, lambda name: (name in FIRST_PICTURES) == first)
        return {"pictures": drawn, "seconds": time.perf_counter() - started}
    except Exception:  # noqa: BLE001 (told to the parent, which raises it)
        return {"error": traceback.format_exc()}
    finally:
        gc.enable()


def _write_fields(model, shot, out: Path, device) -> None:
    """fields.npz: the measured field (a :class:`~modalctl.model.records.FieldRecord`: the model's
    modes on the grid as its basis plus what they leave, every sample within 2^-16 of the peak, or
    of an eighth of the noise; a simulator's field stored as the modes it made it of and its noise as
    its generator's key), the target, the capture and the modal coefficients."""
    import numpy as np

    from modalctl.io.device import scan_indices
    from modalctl.model.records import write_field_record
    from modalctl.outdir import atomic

    coeffs = shot.coefficients()
    extra = dict(focus_field=shot.focus_field, target=shot.decomposition.shape.values,
                 target_mask=shot.decomposition.shape.target_mask, sample_times=shot.capture.times,
                 voltages=shot.capture.voltages, sensors=shot.capture.sensors, focus_point_velocity=shot.focus_velocity,
                 labels=np.asarray(model.labels), **{f"coefficients_{k}": v for k, v in coeffs.items()})
    caps = device.capabilities
    points = None if caps is None else scan_indices(caps, model.grid.points, device.url)  # as the shot scanned
    noise, modes = device.scan_noise_stream(shot.times, points), device.scan_modes(shot.times, points)
    with atomic(out / "fields.npz") as temporary:
        write_field_record(temporary, shot.times, model.grid.points, shot.field, extra=extra, noise=noise,
                           basis=model.shapes.T, modes=modes)


def _print_shot(args, m: dict, report) -> None:
    """The focus: modes, tau, the margin measured and planned (``report``: the plan's
    :class:`~modalctl.plan.planner.PlanReport`), the voltage and the times."""
    params = " ".join(f"{k}={v}" for k, v in args.param)
    print(f"{m['scene']}, {args.shape} {params}, T_F {args.focus_time * 1e3:g} ms, truth: {m['truth']}")
    grown = m["model"]["grown"]
    if grown:
        print(f"model grown from {grown['from_modes']} modes below {grown['from_band_hz']:.0f} Hz to "
              f"{grown['modes']} below {grown['band_hz']:.0f} Hz: {grown['reason']} (now {grown['tau']:.3f})")
    print(f"modes {m['modes_used']}")
    print(f"tau {m['tau']:.4f} (model {m['tau_model']:.4f})  tau_norm {m['tau_norm']:.4f}  NRMSE {m['nrmse']:.4f}")
    held = m["margin_planned"]
    if held is not None and held != m["margin_criterion"]:
        band = (m["program"] or {}).get("robust_drift")
        print(f"the closed loop's plan holds {held:g} (headroom for its feedback)"
              + (f" over +-{100 * band:g}% of resonance drift" if band else ""))
    planned = (f"planned {m['whole_model_margin_ratio']:.3f} on every sample of the whole model"
               if report.predicted_margin_ratio is None else f"planned {m['predicted_margin_ratio']:.3f} on the kept "
               f"modes, {m['whole_model_margin_ratio']:.3f} predicted on the whole model")
    print(f"margin ratio {m['margin_ratio']:.3f} measured ({'met' if m['margin_ok'] else 'NOT met'}: criterion "
          f"{m['margin_criterion']:g}); {planned}; peak voltage {m['peak_voltage']:.1f} V"
          + (f" (limit {m['voltage_limit_v']:g} V)" if m.get("voltage_limit_v") is not None else ""))
    print(f"plan {m['plan_seconds']:.2f} s ({m['planner']} planner), device {m['sim_seconds']:.2f} s")


def _print_loop(m: dict, shot, out: Path) -> None:
    """The closed loop, the learning shot and the decoupling warnings, when there are."""
    if "loop" in m:
        lp = m["loop"]
        where = "on the board" if lp.get("on_board") else \
            f"{1e6 * (lp['step_seconds_median'] or 0):.0f} us per update ({1e6 * (lp['step_seconds_p99'] or 0):.0f} at 99%)"
        ended = (f"stopped by a fault ({lp['fault']})" if lp["fault"] else
                 f"ran {lp['periods']} periods and ended {lp['state']}")  # inactive: the lifecycle's rest state
        print(f"closed loop at {lp['control_rate_hz'] / 1e3:g} kHz: {ended}, "
              + (f"{lp['periods']} periods, " if lp["fault"] else "") + f"{where}, crossovers "
              f"{min(lp['crossover_hz']):.0f}-{max(lp['crossover_hz']):.0f} Hz; log: {out}/log.json + log.bin")
        print(f"the shot took {lp['real_time_factor']:.2f}x its played time (set-up, loop, log, records; "
              f"design {lp['design_seconds']:.2f} s and the field's scan {lp['scan_seconds']:.2f} s besides)")
        if lp.get("note"):
            print("note: " + lp["note"])
        if lp.get("clusters"):
            c = lp["clusters"]
            how = "each controlled as one" if c["together"] else "per-mode loops that read each other"
            print(f"clusters ({len(c['groups'])}, {how}; linked when {c['rule']}): "
                  + ("" if c["groups"] or c["refused"] else c["lines"][0]))
            for line in c["lines"] if c["groups"] or c["refused"] else ():
                print("  " + line)
    if shot.learning is not None:
        ls = shot.learning
        how = (f"fit {ls.update_seconds:.1f} s, misfit {100 * ls.misfit:.1f}%" if ls.source == "record"
               else "a pole tracker during the shot")
        print(f"learning shot: tau {ls.tau:.4f}, margin ratio {ls.margin_ratio:.3f}; its {ls.source} moved the "
              f"resonances by {100 * ls.common_shift:+.2f}% in common ({100 * min(ls.relative_shift):+.2f}% "
              f"to {100 * max(ls.relative_shift):+.2f}%; {how}); the numbers above are the shot planned again "
              f"on the updated model")
    for w in m["decoupling_warnings"]:
        print("warning: " + w)
