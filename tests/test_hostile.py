"""Issue 39: the tracebacks and silent exits a new user found, each ending in its code (docs/errors.md),
each class closed where it enters: output paths checked before any work, every reader's foreign
exception turned into modalctl's own, sizes read from the headers before any allocation, an option
that does not apply refused, every result written atomically."""

import io
import json
import os
import resource
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from modalctl.cli import main
from modalctl.model import files
from modalctl.model.modes import ModalModel, ModelError
from modalctl.model.scenes import load_scene
from modalctl.outdir import OutDirError, atomic, check_writable

ROOT = Path(__file__).resolve().parents[1]
RUN = ["run", "--scene", "thesis-al-cc", "--points", "61", "--shape", "sinc", "--param", "width=18mm",
       "--focus-time", "25ms", "--quiet", "--no-plots"]
FE = ["model", "fe", "--outline", "rect:100mm,70mm", "--thickness", "1mm", "--modes", "3", "--no-plots"]


def call(argv) -> int:
    try:
        return main(argv)
    except SystemExit as exit_:  # argparse's own refusals
        return exit_.code


@pytest.fixture(scope="module")
def model_file(tmp_path_factory) -> Path:
    return load_scene("thesis-al-cc", 61).save(tmp_path_factory.mktemp("model") / "beam.npz")


def rewritten(source: Path, target: Path, **changes) -> Path:
    """``source``'s arrays with ``changes`` (an array, or a header dict for ``meta_json``)."""
    with np.load(source, allow_pickle=False) as data:
        arrays = {key: data[key] for key in data.files}
    for key, value in changes.items():
        arrays[key] = np.array(json.dumps(value)) if key == "meta_json" else value
    np.savez(target, **arrays)
    return target


@pytest.fixture
def no_work(monkeypatch):
    """Any model or plate solved, any survey begun, fails the test: a refusal comes first."""
    def work(*_, **__):
        raise AssertionError("the command started its work before refusing its output path")

    monkeypatch.setattr("modalctl.model.scenes.load_scene", work)
    monkeypatch.setattr("modalctl.model.fe_plate.FEPlate.modal_model", work)


# -- output paths -------------------------------------------------------------------------------------
@pytest.mark.parametrize("argv, words", [
    ([*RUN, "--out", "/proc/modalctl-x"], "kernel's proc filesystem"),
    ([*RUN, "--out", "/dev/null/x"], "goes through '/dev/null', which is not a directory"),
    ([*RUN, "--out", "/sys/modalctl-x"], "kernel's sysfs filesystem"),
    (["sweep", "--vary", "drift=0,1%", "--out", "/proc/x"], "kernel's proc filesystem"),
    ([*FE, "--out", "/proc/x"], "kernel's proc filesystem"),
    ([*FE, "--out", "/dev/null"], "a device or another special file"),
    ([*FE, "--out", "/tmp"], "is a directory; give a file name"),
    (["identify", "--scene", "thesis-al-cc", "--out", "/proc/x/i.npz"], "--out: '/proc/x/i.npz' is on the kernel's"),
    (["identify", "--scene", "thesis-al-cc", "--out", "/dev/null"], "a device or another special file"),
    (["decompose", "--scene", "thesis-al-cc", "--shape", "sinc", "--save-model", "/proc/m.npz"], "kernel's proc"),
])
def test_an_output_path_that_cannot_take_results_exits_2_before_any_work(capsys, no_work, argv, words):
    """Before: FileNotFoundError or NotADirectoryError from mkdir, for model fe and identify after the solve."""
    assert call(argv) == 2
    assert words in capsys.readouterr().err


def test_check_writable_tells_a_folder_from_a_file(tmp_path):
    (tmp_path / "file").write_text("x")
    check_writable(tmp_path / "new" / "deeper", folder=True)  # made later
    check_writable(tmp_path / "new" / "model.npz", folder=False)
    check_writable(tmp_path / "file", folder=False)  # replaced atomically
    with pytest.raises(OutDirError, match="is a file, not a directory"):
        check_writable(tmp_path / "file", folder=True)
    with pytest.raises(OutDirError, match="goes through"):
        check_writable(tmp_path / "file" / "model.npz", folder=False)


def _limited(argv: list[str], size: int, cwd: Path) -> subprocess.CompletedProcess:
    """``modalctl argv`` in a child whose files may grow to ``size`` bytes (a disk that fills)."""
    def limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (size, size))

    return subprocess.run([sys.executable, "-m", "modalctl", *argv], cwd=cwd, preexec_fn=limit, capture_output=True,
                          text=True, env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=300)


@pytest.mark.slow
def test_a_full_disk_leaves_the_model_that_was_there_whole_and_exits_2(tmp_path, model_file):
    """Before: a traceback, and an existing good model turned into a 16 KB broken file."""
    kept = tmp_path / "plate.npz"
    kept.write_bytes(model_file.read_bytes())
    done = _limited([*FE, "--out", str(kept)], 20_000, tmp_path)
    assert done.returncode == 2, done.stderr
    assert "cannot write" in done.stderr and "Traceback" not in done.stderr
    assert kept.read_bytes() == model_file.read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plate.npz"]  # no temporary left


def test_a_write_the_disk_refuses_is_an_outdir_error_and_the_old_file_stays(tmp_path):
    path = tmp_path / "sweep.json"
    path.write_text("old")
    with pytest.raises(OutDirError, match="cannot write .*No space left"):
        with atomic(path) as temporary:
            temporary.write_text("half")
            raise OSError(28, "No space left on device")
    assert path.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["sweep.json"]


# -- model files and arrays ------------------------------------------------------------------------------
def test_a_model_whose_meta_is_not_an_object_is_refused(model_file, tmp_path):
    """Before: AttributeError ('str' object has no attribute 'get')."""
    with np.load(model_file) as data:
        header = json.loads(str(data["meta_json"]))
    path = rewritten(model_file, tmp_path / "m.npz", meta_json={**header, "meta": "a string"})
    with pytest.raises(ModelError, match="meta: must be a dict"):
        ModalModel.load(path)


def test_nan_mode_labels_are_refused_not_cast(model_file, tmp_path):
    """Before: a NaN label passed as mode -9223372036854775808."""
    with np.load(model_file) as data:
        labels = data["labels"].astype(float)
    for bad in (np.nan, np.inf, 2.5):
        labels[1] = bad
        with pytest.raises(ModelError, match="labels: mode numbers must be whole numbers"):
            ModalModel.load(rewritten(model_file, tmp_path / "m.npz", labels=labels))


def test_duplicate_grid_points_are_refused(model_file, tmp_path):
    with np.load(model_file) as data:
        points = data["points"].copy()
    points[5] = points[4]
    with pytest.raises(ModelError, match="grid points share coordinates"):
        ModalModel.load(rewritten(model_file, tmp_path / "m.npz", points=points))


def test_a_model_larger_than_the_memory_available_is_refused_from_its_headers(model_file, monkeypatch):
    """Before: a 40 MB file asked numpy for 7.45 GiB: the arrays are checked against the memory there is."""
    monkeypatch.setattr(files, "memory_available", lambda: 10_000)
    with pytest.raises(ModelError, match="more than the .* GiB of memory available: refused unread"):
        ModalModel.load(model_file)


def test_an_encrypted_or_foreign_compressed_member_is_refused(model_file, tmp_path):
    path = tmp_path / "odd.npz"
    with zipfile.ZipFile(model_file) as source, zipfile.ZipFile(path, "w") as target:
        for info in source.infolist():
            target.writestr(info, source.read(info), compress_type=zipfile.ZIP_BZIP2)
    with pytest.raises(ModelError, match="encrypted or compressed otherwise"):
        ModalModel.load(path)


@pytest.fixture
def values(tmp_path) -> dict:
    """Files given to ``--shape array --param values=``: an npz named .npy, an npy whose header
    declares 7 TiB in 192 bytes, a text array."""
    with open(tmp_path / "archive.npy", "wb") as handle:
        np.savez(handle, a=np.ones(61))
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False, "shape": (10**12,)})
    (tmp_path / "huge.npy").write_bytes(header.getvalue())
    np.save(tmp_path / "text.npy", np.array(["a"] * 61))
    return {name: str(tmp_path / f"{name}.npy") for name in ("archive", "huge", "text")}


@pytest.mark.parametrize("name, words", [("archive", "is a zip archive (an .npz?)"),
                                         ("huge", "declares 8000000000000 bytes of data and holds 0"),
                                         ("text", "not real numbers")])
def test_an_array_file_that_is_not_one_exits_2(capsys, values, name, words):
    """Before: AttributeError ('NpzFile' has no attribute 'astype'), numpy allocating 7.28 TiB."""
    code = call(["decompose", "--scene", "thesis-al-cc", "--points", "61", "--shape", "array", "--param",
                 f"values={values[name]}"])
    assert code == 2 and words in capsys.readouterr().err


# -- universal files -------------------------------------------------------------------------------------
@pytest.fixture
def uff_file(tmp_path) -> Path:
    pytest.importorskip("pyuff")
    from test_uff import grid_points, mobility, write

    points = grid_points(4, 3)
    return write(tmp_path / "plate.uff", points, mobility(points))


@pytest.mark.parametrize("cut", [0.3, 0.5, 0.9, 0.999])
def test_a_truncated_universal_file_is_refused_not_half_read(uff_file, cut):
    """Before: a file cut in half was read as its first complete datasets (5 of 11 nodes)."""
    text = uff_file.read_bytes()
    uff_file.write_bytes(text[:int(len(text) * cut)])
    with pytest.raises(ModelError, match="cut inside a dataset .* truncated or damaged"):
        files.read_uff_sets(uff_file)


def test_a_damaged_universal_file_is_modalctls_error_not_pyuffs(uff_file, capsys):
    """Before: pyuff's bare Exception('Error when reading data-set(s).') as a traceback."""
    uff_file.write_text(uff_file.read_text().replace("e+00", "x+00", 3))
    code = call(["identify", "--frf", str(uff_file), "--mass-per-area", "1kg/m^2", "--no-plots",
                 "--out", str(uff_file.with_suffix(".npz"))])
    assert code == 2 and "cannot be read" in capsys.readouterr().err


# -- options that do not apply ---------------------------------------------------------------------------
@pytest.mark.parametrize("options, words", [
    (["--touch-at", "10mm"], "--touch-at tells a controller that estimates the touch"),
    (["--loop", "closed", "--controller", "pi", "--touch-at", "10mm"], "--touch-at tells a controller that estimates the touch"),
    (["--planner", "envelope", "--robust-drift", "1%"], "--robust-drift holds the convex planner's margin"),
    (["--margin", "none", "--robust-drift", "1%"], "--robust-drift holds the convex planner's margin"),
    (["--planner", "envelope", "--slew-limit", "1V/s"], "--slew-limit is planned for by the convex planner only"),
])
def test_an_option_the_other_choices_make_meaningless_exits_2(capsys, no_work, tmp_path, options, words):
    """Before: accepted and ignored (the envelope planner played 94,000 V/s under --slew-limit 1V/s, exit 0)."""
    assert call([*RUN, *options, "--out", str(tmp_path / "out")]) == 2
    assert words in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_an_allocation_no_estimate_refused_ends_in_exit_2_not_a_traceback(capsys, monkeypatch, tmp_path):
    """Before: numpy's MemoryError (3.26 GiB) as a traceback from a stiff elastic rim at --tolerance 1e-5."""
    def allocate(*_, **__):
        raise MemoryError("Unable to allocate 3.26 GiB for an array with shape (21000, 21000) and data type float64")

    monkeypatch.setattr("modalctl.model.fe_plate.FEPlate.modal_model", allocate)
    assert call([*FE, "--out", str(tmp_path / "plate.npz")]) == 2
    assert "more memory than there is (Unable to allocate 3.26 GiB" in capsys.readouterr().err


# -- controllers -----------------------------------------------------------------------------------------
@pytest.mark.parametrize("controller", ["lqg", "cluster"])
def test_the_observer_controllers_run_on_a_noiseless_truth(capsys, tmp_path, controller):
    """Before: exit 2 with scipy's "Reordering of (A, B) failed ... very ill-conditioned" for a valid run: the
    Kalman filter's covariances at the noise floor (1e-17) broke scipy's pencil; solved at unit noise now."""
    code = call([*RUN, "--points", "211", "--loop", "closed", "--controller", controller, "--out", str(tmp_path)])
    assert code == 0, capsys.readouterr().err
    assert json.loads((tmp_path / "metrics.json").read_text())["tau"] > 0.95


# -- finite-element grids ----------------------------------------------------------------------------------
PLATE = ["--shape", "bump", "--param", "width=30mm", "--param", "center=-20mm,5mm", "--focus-time", "25ms"]


@pytest.mark.parametrize("argv, words", [
    (["run", "--scene", "plate-glass-clamped", "--points", "3x3", *PLATE, "--no-plots", "--quiet"],
     "a 50 mm grid has 9 points, too coarse to tell 21 modes apart"),
    (["run", "--scene", "panel-rounded", "--points", "1000x2", *PLATE, "--no-plots", "--quiet"],
     "a 70 mm grid has 6 points, too coarse to tell 45 modes apart"),
    (["sweep", "--scene", "plate-glass-clamped", "--points", "2x2", *PLATE, "--vary", "drift=0", "--methods", "open",
      "--workers", "1", "--quiet"], "a 100 mm grid has 4 points, too coarse to tell 21 modes apart"),
    ([*FE[:-2], "21", "--spacing", "100mm", "--no-plots"], "a 100 mm grid has 4 points, too coarse"),
])
def test_a_finite_element_grid_with_fewer_points_than_modes_exits_2_saying_so(capsys, tmp_path, argv, words):
    """Before: scipy's "A singular matrix detected" (3x3), or "converging 21 modes ... needs a mesh above 400000
    degrees of freedom: the band is too high" (2x2): the grid, not the band, was too coarse."""
    out = str(tmp_path / ("plate.npz" if argv[0] == "model" else "out"))
    assert call([*argv, "--out", out]) == 2
    assert words in capsys.readouterr().err


# -- places off a plate within its bounds ------------------------------------------------------------------
PANEL = ["run", "--scene", "panel-rounded", "--shape", "bump", "--param", "width=30mm", "--focus-time", "25ms",
         "--no-plots", "--quiet"]


@pytest.mark.parametrize("options, words", [
    (["--param", "center=0mm,0mm", "--finger-at", "42mm,0mm", "--finger", "1"], "the finger: a touch at [42.0, 0.0]"),
    (["--param", "center=42mm,0mm"], "center: 42 mm, 0 mm lies off the structure: in a hole"),
    (["--param", "center=0mm,0mm", "--loop", "closed", "--touch-at", "59.5mm,34.5mm"], "a touch at [59.5, 34.5] mm"),
])
def test_a_place_in_a_hole_or_past_a_rounded_corner_exits_2(capsys, tmp_path, options, words):
    """Before: panel-rounded's slot and rounded corners lie within its grid's bounds, on lattice points of no
    mass where no mode moves: a finger there did nothing (exit 0, 'truth: finger 1 N s/m at 42, 0 mm'), the
    touch controller sensed nothing, a centre there was planned until its tau failed (exit 1)."""
    assert call([*PANEL, *options, "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert words in err and "off the structure: in a hole, on its rim or past it" in err


def test_a_finger_sliding_over_the_slot_lifts_there_and_lands_past_it():
    from modalctl.hil.scenario import Perturbation

    model = load_scene("panel-rounded")
    path = Perturbation(finger=1.0, finger_at=(0.020, 0.0), finger_lands=0.0, finger_slide=1.0).touch_path(model)
    assert path(0.001) is not None  # at 21 mm
    assert path(0.022) is None  # at 42 mm: over the slot, no contact (before: ModelError mid-shot)
    assert path(0.037) is not None  # at 57 mm: past the slot (32-52 mm), on the plate


@pytest.mark.parametrize("argv, words", [
    (["sweep", "--vary", "focus-time=10s", "--methods", "open"], "is 5e+06 samples per channel; at most 1e+06"),
    (["sweep", "--vary", "drift=0", "--methods", "closed", "--control-rate", "7kHz"],
     "the control rate 7000 Hz must divide the DAC rate 500000 Hz"),
    ([*RUN, "--loop", "closed", "--control-rate", "7kHz"], "the control rate 7000 Hz must divide the DAC rate 1e+06"),
    ([*RUN, "--loop", "closed", "--control-rate", "2MHz"], "the control rate 2e+06 Hz must divide the DAC rate"),
    # before: exit 4, a traceback from the plant's propagation (no period in the shot); 100 Hz ran 2 periods
    ([*RUN, "--loop", "closed", "--control-rate", "10Hz"], "the closed loop at 10 Hz has 0 control periods"),
    ([*RUN, "--loop", "closed", "--control-rate", "100Hz"], "has 2 control periods in the shot"),
])
def test_a_shot_s_options_are_refused_before_out_is_claimed_or_a_plan_made(capsys, request, tmp_path, argv, words):
    """Before: sweep refused these in its first case, leaving run.json in --out; the control rate was checked
    by the loops' schedule, after the plan (run: before the model too; a sweep reads it for its voltage limit)."""
    if argv[0] == "run":
        request.getfixturevalue("no_work")
    assert call([*argv, "--workers", "1", "--quiet", "--out", str(tmp_path / "out")] if argv[0] == "sweep"
                else [*argv, "--out", str(tmp_path / "out")]) == 2
    assert words in capsys.readouterr().err and not (tmp_path / "out").exists()


def test_a_sample_rate_below_the_kept_modes_nyquist_is_bad_input(capsys, tmp_path):
    """Before: ``--sample-rate 1Hz`` exited 1 ("no plan", a target the structure cannot meet) with the voltage
    limit's note appended; the option itself cannot serve the scene: exit 2, naming the rate it needs (twice
    the highest kept mode of the beam's sinc: its 14355 Hz mode)."""
    assert call([*RUN, "--sample-rate", "1Hz", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "sample rate 1 Hz is below twice the highest kept mode" in err and "give --sample-rate above" in err
    assert "voltage" not in err
