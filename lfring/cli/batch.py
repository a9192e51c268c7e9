"""``lfring batch``: refocus, depth and all-in-focus for whole folders of frames."""

from __future__ import annotations

import logging

import click

from lfring.cli._options import aperture_options, check_option, output_folder, parse_depths, raw_options
from lfring.core.warping import DEFAULT_INTERPOLATION

log = logging.getLogger("lfring.cli.batch")


def _refocus_depths(text: str) -> tuple[float, ...]:
    """--refocus as depths in metres, read as lfring refocus reads --depths; refused, naming
    --refocus, where they break the batch's rule (:func:`lfring.batch.settings.refocus_depth_problem`),
    before any frame is looked for."""
    from lfring.batch.settings import refocus_depth_problem

    zs = parse_depths(text, param_hint="--refocus")
    problem = refocus_depth_problem(zs)
    if problem:
        raise click.BadParameter(problem, param_hint="--refocus")
    return zs


@click.command("batch")
@click.argument("inputs", nargs=-1, required=True, metavar="INPUT...")
@click.option("-o", "--output", "outdir", type=click.Path(file_okay=False), required=True, callback=output_folder, metavar="OUTDIR",
              help="Output folder (created; folder inputs keep their structure inside it).")
@click.option("--calib", type=click.Path(dir_okay=False), default=None, metavar="FILE",
              help="Calibration JSON for every frame (default: the built-in one for each frame's size).")
@click.option("--refocus", "refocus_m", default=None, metavar="Z1,Z2,...", help="Refocus every frame at these depths [m].")
@click.option("--method", "refocus_method", type=click.Choice(["depth-aware", "shift-and-add"]), default="depth-aware",
              show_default=True,
              help="Refocusing of --refocus and of the --viewer's focal stack, as lfring refocus --method: depth-aware "
                   "renders what the lens's whole aperture would record from each frame's depth map (the --depth map when "
                   "there is one, else one estimated over --zmin..--zmax or the calibration's range); "
                   "shift-and-add averages the views (out-of-focus objects as four copies; much faster). Each frame's "
                   "record says which method and aperture made its images.")
@aperture_options
@click.option("--depth", "depth_map", is_flag=True,
              help="Depth map of every frame over --zmin..--zmax (default: the calibration's range, as lfring depth).")
@click.option("--zmin", type=float, default=None, metavar="M",
              help="Nearest depth of every depth map [m]: --depth's, the one --method depth-aware refocuses from, the "
                   "--viewer's (default: the calibration's valid range).")
@click.option("--zmax", type=float, default=None, metavar="M",
              help="Farthest depth of every depth map [m] (default: the calibration's valid range; for one open to "
                   "infinity, where the views stop moving).")
@click.option("--planes", type=int, default=None, metavar="N", help="Depth hypotheses (default: 1 px of view motion apart).")
@click.option("--depth-method", type=click.Choice(["sgm", "local"]), default="sgm", show_default=True,
              help="Depth maps by semi-global optimisation, or by the local sweep (faster on small frames; see lfring "
                   "depth --method).")
@click.option("--all-in-focus", "aif", is_flag=True,
              help="All-in-focus image of every frame: from its depth map when the batch makes one (--depth, or "
                   "depth-aware --refocus; not --viewer's own), else where the views agree best.")
@click.option("--viewer", is_flag=True, help="Interactive HTML viewer of every frame, NAME_viewer.html (see lfring view).")
@click.option("--reference", default="center", show_default=True, metavar="center|0..3", help="Frame of the results.")
@click.option("--interpolation", type=click.Choice(["cubic", "linear"]), default=DEFAULT_INTERPOLATION, show_default=True,
              help="Resampling of the views for refocusing.")
@click.option("--bit-depth", type=click.Choice(["8", "16"]), default="8", show_default=True, help="Bits per sample of images.")
@click.option("--encoding", type=click.Choice(["srgb", "linear"]), default="srgb", show_default=True,
              help="sRGB-encoded or linear images.")
@click.option("--workers", type=int, default=None, metavar="N", help="Worker processes (default: the number of cores).")
@click.option("--executor", type=click.Choice(["local", "dask"]), default="local", show_default=True,
              help="Process pool on this machine, or a Dask cluster (pip extra 'dask').")
@click.option("--scheduler", default=None, metavar="ADDRESS",
              help="Dask scheduler, e.g. tcp://10.0.0.5:8786 (default with --executor dask: a local cluster).")
@click.option("--exclude", multiple=True, metavar="GLOB",
              help="Leave out files whose name, path below a folder given, or path as given matches this pattern "
                   "(repeatable).")
@click.option("--progress/--no-progress", default=None, help="Progress bar (default: when stderr is a terminal).")
@click.option("--overwrite", is_flag=True, help="Redo frames already done and replace existing files.")
@raw_options
@check_option
@click.pass_context
def command(ctx, inputs, outdir, calib, refocus_m, refocus_method, aperture, f_number, depth_map, zmin, zmax, planes, depth_method,
            aif, viewer, reference, interpolation, bit_depth, encoding, workers, executor, scheduler, exclude, progress, overwrite,
            levels, no_check):
    """Process every frame of INPUT... (files, folders searched recursively, glob patterns).

    Each frame gets its outputs in OUTDIR (refocused images NAME_refocus_<Z>m.png, depth-aware
    by default as with lfring refocus, depth maps NAME_depth.tiff with NAME_confidence.tiff and
    NAME_depth_preview.png, NAME_all_in_focus.png) and a record NAME.lfring.json, which says
    which method and aperture made its images; OUTDIR/manifest.jsonl gets a line per frame with
    the files written for it (a manifest.jsonl that lfring did not write is refused unless
    --overwrite). A folder refocused with one method is not done for another. Frames already
    done with the same settings are skipped, and a rerun that adds an output (another --refocus
    depth, --depth) computes only what is missing; an output that the new settings would make
    differently (depth-aware images when --zmin/--zmax change their depth map's range, the
    all-in-focus image once depth-aware --refocus gives it a depth map) is refused with the
    setting named, or redone with --overwrite. A bad frame is reported by name
    and the rest go on. Folder walks leave out files that are not frames (sidecars, *_truth/
    folders, images of a size no calibration fits): one line says how many, -v lists them; flat
    (white) frames are read and left out with that reason. Ctrl-C or SIGTERM stops the workers
    at once (exit code 130 or 143); what was written is whole, and a rerun goes on from there.
    Exit code: 0 all frames done or skipped, 1 some failed, 2 bad usage.
    """
    from lfring.batch import BatchSettings, run_batch
    from lfring.core.geometry import check_reference

    zs = _refocus_depths(refocus_m) if refocus_m is not None else ()
    if not (zs or depth_map or aif or viewer):
        raise click.UsageError("nothing to do: give --refocus Z1,Z2,..., --depth, --all-in-focus or --viewer")
    if (zmin is not None or zmax is not None) and not (depth_map or viewer or (zs and refocus_method == "depth-aware")):
        raise click.UsageError("--zmin/--zmax go with --depth, --viewer or --refocus by --method depth-aware "
                               "(the range of their depth maps); nothing here makes a depth map")
    if not (zs or viewer):
        given = [flag for flag, name in (("--method", "refocus_method"), ("--aperture", "aperture"), ("--f-number", "f_number"))
                 if ctx.get_parameter_source(name) is not click.core.ParameterSource.DEFAULT]
        if given:
            raise click.UsageError(f"{', '.join(given)} choose{'s' if len(given) == 1 else ''} how --refocus images and "
                                   "the --viewer's focal stack are made; --depth and --all-in-focus have no method or "
                                   "depth of field")
    if refocus_method != "depth-aware" and (aperture is not None or f_number is not None):
        raise click.UsageError("--aperture and --f-number are for --method depth-aware")
    if aperture is not None and f_number is not None:
        raise click.UsageError("give --aperture or --f-number, not both")
    if scheduler and executor != "dask":
        if ctx.get_parameter_source("executor") is click.core.ParameterSource.COMMANDLINE:
            raise click.UsageError(f"--scheduler {scheduler} is a Dask scheduler: give --executor dask (or leave "
                                   f"--executor out), not --executor {executor}")
        executor = "dask"
    cal = None
    cal_name = "built-in"
    if calib:
        from lfring.calibration import RingCalibration

        cal, cal_name = RingCalibration.load(calib), calib
        ref = check_reference(reference, cal.num_views)
    else:
        ref = check_reference(reference, 4)
    settings = BatchSettings(refocus_m=zs, refocus_method=refocus_method, aperture=aperture, f_number=f_number,
                             depth=depth_map, zmin_m=zmin, zmax_m=zmax, all_in_focus=aif, calibration=cal,
                             calibration_name=cal_name, reference=ref, interpolation=interpolation, bit_depth=int(bit_depth),
                             encoding=encoding, planes=planes, depth_method=depth_method, viewer=viewer,
                             check_frames=not no_check,
                             **levels.as_kwargs())
    try:
        report = run_batch(list(inputs), outdir, settings, workers=workers, executor=executor, scheduler=scheduler,
                           overwrite=overwrite, exclude=exclude, progress=progress)
    except KeyboardInterrupt:  # Ctrl-C, or SIGTERM raised as one: main says which, after this line
        click.echo(f"lfring batch: stopped; what it wrote to {outdir} is whole, and the same command again goes on "
                   "from there", err=True)
        raise
    # Each failure was logged once as it happened (lfring.batch); the summary counts them.
    verbose = ctx.find_root().params.get("verbose", 0)
    if report.not_frames and verbose:
        for path, why in report.not_frames:
            click.echo(f"not a frame: {path}: {why}", err=True)
    click.echo(report.summary() + ("" if not report.not_frames or verbose else " (-v lists them)"))
    if report.exit_code:
        ctx.exit(report.exit_code)
