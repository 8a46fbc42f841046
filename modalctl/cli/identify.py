"""``modalctl identify``: a structure's modes identified from FRFs, swept through a device
(``sim://`` by default) or read from a universal file, written as a model file."""

from __future__ import annotations

import json
from pathlib import Path

from modalctl.options import VOLTAGE_MIN, SurveyOptions
from modalctl.units import number_type, quantity_type

from .common import open_device, out_file, progress_bars, stage

NAME, HELP = "identify", "identify a structure's modes from FRFs measured through a device"
SURVEY = SurveyOptions()  # the defaults the options below show and use
SCAN_POINTS_MIN = 5  # scan points a mode shape needs
SNR = 40.0  # dB: the simulated vibrometer's noise below the largest velocity, unless --snr says
RESOLUTION_MAX = 1e4  # Hz: a sweep of 0.1 ms at least (1e300 Hz had been taken for a channel not connected)
AMPLITUDE_MAX = 1e4  # V: above any piezo driver's rails (1e300 V, as 1e-300 V, had been blamed on the channel)
SWEEP = {"f_low": 100.0, "f_high": 100e3, "resolution": 4.0, "amplitude": 15.0, "step": 1e-3}  # defaults of the sweep
SURVEY_ONLY = ("resolution", "amplitude", "step", "primary", "averages")  # options a file's FRFs have no use for


def add_parser(sub):
    return sub.add_command(NAME, HELP, add_arguments, run)


def add_arguments(p) -> None:
    from modalctl.io.device import add_transport_options

    p.add_argument("--transport", default="sim://", help="device URL (default sim://)")
    p.add_argument("--scene", help="sim://: the structure simulated (and its mass per length by default)")
    p.add_argument("--frf", help="identify from measured FRFs in a universal file (datasets 58 and 15) instead")
    p.set_defaults(transports=add_transport_options(p), snr=None)  # SNR on sim:// unless said; said with --frf: refused
    p.add_argument("--f-low", type=quantity_type("Hz", "f-low", low=0, low_open=False),
                   help=f"sweep start ({SWEEP['f_low']:g}Hz); with --frf the band's start (the file's)")
    p.add_argument("--f-high", type=quantity_type("Hz", "f-high", low=0),
                   help=f"sweep end ({SWEEP['f_high'] / 1e3:g}kHz); with --frf the band's end (the file's)")
    p.add_argument("--resolution", type=quantity_type("Hz", "resolution", low=0, high=RESOLUTION_MAX),
                   help=f"FRF resolution = 1 / T_sweep ({SWEEP['resolution']:g}Hz)")
    p.add_argument("--amplitude", type=quantity_type("V", "amplitude", low=VOLTAGE_MIN, high=AMPLITUDE_MAX,
                                                     low_open=False),
                   help=f"sweep peak voltage ({SWEEP['amplitude']:g}V)")
    p.add_argument("--step", type=quantity_type("m", "step", low=0),
                   help=f"spatial step of the scan, in each direction on a plate ({SWEEP['step'] * 1e3:g}mm)")
    p.add_argument("--mass-per-length", type=quantity_type("kg/m", "mass-per-length", low=0),
                   help="of a beam (kg/m); default from the scene")
    p.add_argument("--mass-per-area", type=quantity_type("kg/m^2", "mass-per-area", low=0),
                   help="of a plate (kg/m^2); default from the scene")
    p.add_argument("--method", default=SURVEY.method,
                   help=f"identifier plugin: auto, sdof, mdof or peaks (see 'modalctl plugins'; {SURVEY.method})")
    p.add_argument("--primary", type=number_type(int, "primary", low=0, low_open=False),
                   help=f"actuator swept over the whole grid ({SURVEY.primary})")
    p.add_argument("--averages", type=number_type(int, "averages", low=1, high=1000, low_open=False),
                   help=f"shots per point ({SURVEY.averages})")
    p.add_argument("--no-orthogonalize", action="store_true",
                   help="skip Gram-Schmidt (it is applied only where the grid's weights integrate the modes)")
    p.add_argument("--left-out", action="store_true", help="list every mode left out, peaks of the noise too")
    p.add_argument("--out", required=True, type=out_file, help="model file to write (.npz); pictures beside it")
    p.add_argument("--no-plots", action="store_true")
    p.add_argument("--json", action="store_true")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _density(args, meta: dict, dim: int) -> float:
    """Mass per length (beam, kg/m) or per area (plate, kg/m^2) for a survey on ``dim``-D points:
    the option, or the scene's; the other option is refused."""
    from modalctl.model.shape import ParamError

    wanted, other = ("mass_per_length", "mass_per_area") if dim == 1 else ("mass_per_area", "mass_per_length")
    flag = "--" + wanted.replace("_", "-")
    if getattr(args, other) is not None:
        raise ParamError(f"identify: the points are {'on a line' if dim == 1 else 'on a plate'}: give {flag}, "
                         f"not --{other.replace('_', '-')}")
    if getattr(args, wanted) is not None:
        return getattr(args, wanted)
    try:
        per_area = meta["density_kg_m3"] * meta["thickness_m"]
        return per_area if dim == 2 else per_area * meta["width_m"]
    except KeyError:
        unit = "kg/m" if dim == 1 else "kg/m^2"
        raise ParamError(f"identify: give {flag} ({unit}): it scales the shapes and gains") from None


def _refuse_survey_options(args) -> None:
    """With ``--frf``, the options only a sweep through a device uses are refused, each named."""
    from modalctl.model.shape import ParamError

    given = [f"--{name}" for name in SURVEY_ONLY if getattr(args, name) is not None]
    if args.transport != "sim://":
        given.append("--transport")
    given += args.transports.misplaced(args, "")  # every transport's options: no device is opened
    if given:
        named = given[0] if len(given) == 1 else f"{', '.join(given[:-1])} and {given[-1]}"
        raise ParamError(f"identify: {named} {'does' if len(given) == 1 else 'do'} not apply to --frf (FRFs read "
                         f"from a file, no sweep through a device); leave {'it' if len(given) == 1 else 'them'} out")


def _from_file(args, meta: dict):
    """The survey of the FRFs in ``--frf``, within ``--f-low``/``--f-high``: (survey, point indices)."""
    import numpy as np

    from modalctl.identify.survey import identify_frf
    from modalctl.identify.uff import read_uff58_references
    from modalctl.model.shape import ParamError

    _refuse_survey_options(args)
    frfs = read_uff58_references(args.frf)
    f = frfs[0].frequencies
    low = f[0] if args.f_low is None else args.f_low
    high = f[-1] if args.f_high is None else args.f_high
    inside = np.count_nonzero((f >= low) & (f <= high))
    if inside < 8:
        raise ParamError(f"identify: --f-low {low:g} Hz to --f-high {high:g} Hz holds {inside} of the file's lines "
                         f"({f[0]:g} to {f[-1]:g} Hz every {f[1] - f[0]:.4g} Hz); at least 8 are needed")
    if args.f_low is not None or args.f_high is not None:
        frfs = [frf.band(low, high) for frf in frfs]
    density = _density(args, meta, frfs[0].points.shape[1])
    survey = identify_frf(frfs if len(frfs) > 1 else frfs[0], density, args.method, not args.no_orthogonalize)
    if args.f_low is not None or args.f_high is not None:
        survey.notes.insert(0, f"band {low:g} to {high:g} Hz of the file's {f[0]:g} to {f[-1]:g} Hz")
    return survey, np.arange(survey.model.grid.n)


def run(args) -> int:
    import numpy as np

    from modalctl.model.modes import ModelError
    from modalctl.model.scenes import load_scene

    scene = load_scene(args.scene) if args.scene else None
    if args.frf is None and args.transport.startswith("sim") and scene is None:
        raise ModelError("identify: the simulator needs --scene (the structure to simulate)")
    meta = scene.meta if scene is not None else {}
    survey, points = _from_file(args, meta) if args.frf else _survey(args, scene, meta)
    if scene is not None and scene.voltage_limit is not None and args.frf is None and args.transport.startswith("sim"):
        from dataclasses import replace  # the simulated structure's patches are the scene's: their safe voltage

        survey.model = replace(survey.model, meta={**survey.model.meta, "voltage_limit_v": scene.voltage_limit,
                                                   "voltage_limit_source": scene.meta.get("voltage_limit_source")})
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    path = survey.model.save(out)
    off = lambda c: float(np.max(np.abs(c - np.eye(len(c))))) if len(c) else 0.0  # noqa: E731
    poles = survey.poles
    left = [row for row in poles.summary() if not row["resolved"]]
    summary = {"model_file": str(path), "modes": survey.model.n_modes, "method": args.method,
               "frequencies_hz": survey.model.frequencies.tolist(), "damping": survey.model.damping.tolist(),
               "unit": next(iter(survey.frfs["full"].values())).unit, "poles": poles.summary(), "left_out": left,
               "notes": survey.notes, "seconds": survey.seconds, "points": int(points.size),
               "orthogonalized": survey.orthogonalized, "shape_mac_after_orthogonalization": survey.shape_mac.tolist(),
               "crosstalk_max_before": off(survey.crosstalk_before), "crosstalk_max_after": off(survey.crosstalk_after)}
    if not args.no_plots:
        from modalctl.report import plot_identification

        summary["pictures"] = plot_identification(survey, path.with_suffix(""))
    if args.json:
        print(json.dumps(summary))
        return 0
    _print(args, survey, summary, points, path)
    return 0


def _survey(args, scene, meta: dict):
    """A stepped-sine survey through the device at ``--transport``: (survey, scan point indices)."""
    import numpy as np

    from modalctl.identify.frf import Sweep
    from modalctl.identify.survey import beam_wavelength, identify_device, scan_subset
    from modalctl.model.shape import ParamError

    given = {name: getattr(args, name) for name in ("f_low", "f_high", *SURVEY_ONLY)}
    opt = {name: SWEEP.get(name, getattr(SURVEY, name, None)) if value is None else value
           for name, value in given.items()}
    sweep = Sweep.design(opt["f_low"], opt["f_high"], opt["resolution"], opt["amplitude"])
    options = SurveyOptions(method=args.method, primary=opt["primary"], averages=opt["averages"],
                            orthogonalize=not args.no_orthogonalize)
    if args.snr is None and args.transport.startswith("sim"):  # (another transport's options refuse --snr)
        args.snr = SNR
    stage(args, f"the survey: {opt['f_low']:g} to {opt['f_high']:g} Hz swept through {args.transport}")
    with open_device(args, scene) as device:
        caps = device.configure(sweep.sample_rate)
        scan = np.asarray(caps.scan_points, float).reshape(len(caps.scan_points), -1)
        density = _density(args, meta, scan.shape[1])
        points = scan_subset(scan, opt["step"])
        if points.size < SCAN_POINTS_MIN ** scan.shape[1]:  # said now, not after the whole survey
            raise ParamError(f"identify: --step {opt['step'] * 1e3:g} mm leaves {points.size} scan point(s) on "
                             f"{' x '.join(f'{e * 1e3:.0f}' for e in np.ptp(scan, axis=0))} mm; at least "
                             f"{SCAN_POINTS_MIN} per direction draw a mode shape")
        survey = identify_device(device, sweep, points, density, options, beam_wavelength(meta, opt["f_high"]),
                                 progress=progress_bars(args), stage=lambda text: stage(args, text))
    return survey, points


def _print(args, survey, summary: dict, points, path: Path) -> None:
    print(f"identified {summary['modes']} modes on {points.size} points with {args.method} "
          f"({survey.seconds['frf'] + survey.seconds['modal']:.2f} s compute; FRFs in {summary['unit']})")
    mac = survey.shape_mac if survey.orthogonalized else None
    print(f"{'mode':>5s} {'f (Hz)':>10s} {'zeta':>9s}" + (f" {'MAC GS':>7s}" if mac is not None else ""))
    for i, (f, z) in enumerate(zip(survey.model.frequencies, survey.model.damping)):
        print(f"{i + 1:5d} {f:10.1f} {z:9.5f}" + (f" {mac[i]:7.4f}" if mac is not None else ""))
    notes = [n for n in survey.notes if " left out" not in n and "peak(s) of the noise" not in n]
    lines = survey.poles.left_out(None, noise=True) if args.left_out else survey.poles.left_out()
    for note in [*notes, *lines]:
        print("note: " + note)
    if survey.orthogonalized:
        print(f"cross-talk: max {summary['crosstalk_max_before']:.3f} before Gram-Schmidt, "
              f"{summary['crosstalk_max_after']:.1e} after; MAC of each shape after to before in 'MAC GS'")
    else:
        print(f"cross-talk: max {summary['crosstalk_max_before']:.3f} (no Gram-Schmidt)")
    print(f"model: {path}" + (f"; pictures: {', '.join(summary['pictures'])}" if "pictures" in summary else ""))
