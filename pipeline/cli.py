"""Command line: `python -m pipeline run|validate|bench|matrix|inspect|snapshot|export|sweep ...` (also the `garment-sim` script).

User errors (bad scene, bad asset, bad output path, broken stage input) print one line
`error: ...` naming the scene file and exit 2, without a traceback. Any other exception is a bug:
one line naming the stage, the scene file and the item being processed, exit 1 (`--debug` shows
the traceback). Ctrl-C exits 130, SIGTERM (a `kill`, a job scheduler's stop) the same way with 143. None of them leaves a recording, or a temporary file, behind;
an earlier recording stays.
"""
from __future__ import annotations

import argparse
import signal
import sys
from pathlib import Path

EXIT_USAGE = 2
EXIT_BUG = 1
_interrupted = [False]   # a Ctrl-C (or SIGTERM) arrived during this command
_terminated = [False]    # it was SIGTERM
_cli_process = [False]   # set by `python -m pipeline`: after a Ctrl-C, further ones stay ignored until exit


def _on_sigint(signum, frame):
    # numba's compiler swallows a KeyboardInterrupt raised inside its callbacks and then fails with
    # a RuntimeError ("no compiled object yet"): remember the Ctrl-C, so that error is an interrupt
    _interrupted[0] = True
    signal.default_int_handler(signum, frame)


def _on_sigterm(signum, frame):
    # the same unwinding as Ctrl-C: the temporary recording is removed, the compile process and a
    # sweep's workers stopped, an earlier recording kept
    _terminated[0] = True
    _on_sigint(signal.SIGINT, frame)


def _interrupted_exit() -> int:
    """Report the interrupt, exit code 130. Further Ctrl-Cs are ignored from here on: the process
    is ending, and one landing while it reports or stops its compile process (seconds on a loaded
    machine) ended it by SIGINT instead (CI: exit -2 right after the message)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if _terminated[0]:
        print("\nterminated (SIGTERM): no recording written", file=sys.stderr)
        return 143
    print("\ninterrupted: no recording written", file=sys.stderr)
    return 130


def _user_errors():
    from pipeline.schema import SceneError
    from stages.checks import ContractError
    from stages.errors import InputError
    from stages.sim import SimulationDiverged
    return (SceneError, InputError, ContractError, SimulationDiverged)


def _check_out_file(path, flag: str) -> None:
    """An output file named on the command line (--json, measure -o) is a file path that is not a
    folder, FIFO or device: opened for writing, a FIFO blocks until a reader comes."""
    import os
    import stat

    from stages.errors import InputError
    if path is None:
        return
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return
    if not stat.S_ISREG(mode):
        from stages.input_files import file_kind
        raise InputError(flag, f"{path!r} is {file_kind(mode)}; expected a file path")


def cmd_validate(args) -> int:
    from pipeline import where
    from pipeline.preflight import check_memory, check_references, preflight
    from pipeline.run import character_item, load_character
    from pipeline.scene import load_scene
    scene = load_scene(args.scene)
    meshes = preflight(scene, None, create=False)   # output path, every mesh file, pinned indices
    where.stage("rig")
    with where.item(character_item(scene)):
        character = load_character(scene)
    check_references(scene, character)
    check_memory(scene, scene["frames"]["count"], character.vertices.shape[0], 0)
    patterns = 0
    if scene["garments"]:   # build every garment as a run does, patterns sized and placed but not
        # sewn, on the bind pose: cheap, and where a garment cannot be dressed the error comes before a run
        from pipeline.run import split_and_fit
        from pipeline.scene_motion import frame_times, sample_scene_motion
        from pipeline.dressing import check_scene_garments
        motion = sample_scene_motion(scene, character, frame_times(scene))
        where.stage("colliders")
        _, colliders = split_and_fit(scene, character, motion)
        where.stage("garments")
        patterns = check_scene_garments(scene, character, motion, colliders, meshes)
    from pipeline.scene import warn_notes
    warn_notes(scene)   # implausible values: once every check passed
    print(f"{args.scene}: ok — scene {scene.name!r}, character {character.name!r} "
          f"({character.vertices.shape[0]} vertices, {character.n_joints} joints, "
          f"{len(character.clips)} clips), {len(scene['garments'])} garments built ({patterns} patterns sized and placed, not sewn), "
          f"{len(scene['obstacles'])} obstacles ({len(meshes)} mesh files read), {scene['frames']['count']} frames "
          f"-> {scene.output}")
    for note in character.notes:
        print(f"  {note}")
    return 0


def cmd_run(args) -> int:
    from pipeline.run import run_scene
    from pipeline.scene import load_scene
    scene = load_scene(args.scene)
    def announce(stage: str) -> None:
        if not args.quiet:
            print(f"{stage} ...", file=sys.stderr, flush=True)

    out = Path(args.output) if args.output is not None else scene.output
    summary = run_scene(scene, output=Path(args.output) if args.output is not None else None, frames=args.frames,
                        progress=not args.quiet, on_stage=announce, deterministic=args.deterministic,
                        keep_diverged=out.with_name(out.stem + ".diverged.rrd") if out.name else None,
                        background_compile=True)
    print(summary.text())
    return 0


def cmd_bench(args) -> int:
    from pipeline.bench import run_benchmarks
    _check_out_file(args.json, "--json")
    run_benchmarks(args.which, output=args.json)
    return 0


def cmd_matrix(args) -> int:
    import json

    _check_out_file(args.json, "--json")
    if args.corpus:
        return cmd_corpus(args)
    from pipeline.matrix import run_matrix, table
    results = run_matrix(frames=args.frames, characters_=args.character or None, kinds=args.garment or None,
                         echo=(lambda *a: None) if args.quiet else (lambda *a: print(*a, file=sys.stderr, flush=True)))
    print(table(results))
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0 if all(r["status"] == "ok" or r["status"].startswith("skipped") for per in results.values()
                    for r in per.values()) else 1


def cmd_corpus(args) -> int:
    """matrix --corpus: every character and clip in the assets folder, scenes as a user writes them."""
    import json

    from pipeline.corpus import default_folder, run_corpus, table
    echo = (lambda *a: None) if args.quiet else (lambda *a: print(*a, file=sys.stderr, flush=True))
    kinds = [] if args.only_patterns else (args.garment or None)
    rows = run_corpus(Path(args.output) if args.output else default_folder(), frames=args.frames,
                      characters=args.character or None, kinds=kinds, full=args.full, jobs=args.jobs,
                      patterns=args.pattern or None, with_patterns=not args.no_patterns,
                      pattern_dir=Path(args.patterns) if args.patterns else None, echo=echo)
    print(table(rows))
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1, default=str))
    return 0 if all(not r["verdict"] for r in rows) else 1


def cmd_export(args) -> int:
    """A recording: read its garments and body back; a scene: run it (recording included), then export."""
    from pipeline import export
    formats = export.check_formats([f for arg in args.format for f in arg.split(",") if f])
    src = Path(args.scene)
    if src.suffix in (".yaml", ".yml"):
        from pipeline.run import run_scene
        from pipeline.scene import load_scene
        summary = run_scene(load_scene(src), frames=args.frames, progress=not args.quiet,
                            export=(formats, args.output))
        paths = summary.exports
    elif src.suffix == ".rrd" or not src.exists():
        data = export.from_recording(src)
        paths = export.write(data, formats, args.output or export.default_dir(src))
    else:
        raise export.ExportError(f"{src}: expected a recording (.rrd) or a scene (.yaml)")
    for p in paths:
        print(p)
    return 0


def cmd_sweep(args) -> int:
    """Every combination of a sweep file's overrides as a job (process pool or Ray), the table as
    CSV and Parquet; exit 1 when a job failed (the table says which and why)."""
    from pipeline.sweep import run_sweep, summary_text
    echo = (lambda *a: None) if args.quiet else (lambda *a: print(*a, file=sys.stderr, flush=True))
    try:
        sw, rows = run_sweep(args.scene, output=args.output, jobs=args.jobs,
                             ray_address=False if args.ray is None else args.ray,
                             retry_failed=args.retry_failed, progress=not args.quiet, echo=echo)
    except KeyboardInterrupt:   # the workers are stopped; finished jobs keep their rows
        print(f"\n{'terminated (SIGTERM)' if _terminated[0] else 'interrupted'}: the finished jobs are in the "
              f"table; run the same command to go on", file=sys.stderr)
        return 143 if _terminated[0] else 130
    print(summary_text(sw, rows))
    return 0 if len(rows) == len(sw.jobs) and all(r["status"] == "ok" for r in rows) else 1


def cmd_inspect(args) -> int:
    import json

    from pipeline import where
    from pipeline.inspect import describe, text
    where.stage(f"inspect {args.asset}")
    if str(args.asset).lower().endswith(".json"):     # a GarmentCode pattern (issue 39)
        from pathlib import Path

        from pipeline.pattern_inspect import describe_pattern, pattern_png, pattern_text
        facts = describe_pattern(args.asset)
        png = Path(args.png or f"{facts['name']}_panels.png")
        facts["png"] = str(pattern_png(args.asset, png))
        print(json.dumps(facts, indent=1) if args.json else f"{pattern_text(facts)}\n  panels drawn: {png}")
        return 0
    facts = describe(args.asset)
    print(json.dumps(facts, indent=1) if args.json else text(facts))
    return 0


def cmd_measure(args) -> int:
    """A character's measurements as a GarmentCode body file (issue 39)."""
    from pathlib import Path

    from pipeline import where
    from pipeline.assets import assets_dir
    from pipeline.inspect import load_asset
    from stages.errors import InputError
    from stages.garments.garmentcode_body import body_yaml, gc_body
    from stages.garments.garmentcode_place import DEFAULT_BODY, read_body
    from stages.garments.measurements import garment_measurements
    _check_out_file(args.out, "--out")
    where.stage(f"measure {args.character}")
    character, _ = load_asset(args.character)
    from stages.garments.anchors import require_human
    require_human(character, f"measure {args.character}", subject="a GarmentCode body file is measured")
    default = assets_dir() / DEFAULT_BODY       # the keys a mesh cannot give are scaled from it
    if not default.is_file():
        raise InputError(str(default), "GarmentCode's default body (mean_all.yaml) is not there; set GARMENT_ASSETS "
                                       "to the folder holding garmentcode/bodies/")
    values, estimated = gc_body(garment_measurements(character), read_body(default).values)
    text = body_yaml(values, estimated, args.character)
    if args.out:
        Path(args.out).write_text(text, encoding="utf-8")
        print(f"wrote {args.out}")
    else:
        print(text, end="")
    return 0


def cmd_snapshot(args) -> int:
    from pipeline.snapshot import main
    return main(args)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m pipeline",
                                description="Garment simulation with character colliders, written to Rerun recordings.")
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--debug", action="store_true",
                        help="show the Python traceback of an unexpected error (a bug) instead of one line")
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run", parents=[common], help="run a scene and write its .rrd recording")
    r.add_argument("scene", help="scene .yaml file (see scenes/)")
    r.add_argument("-o", "--output", help="recording path (default: the scene's output, or recordings/<name>.rrd)")
    r.add_argument("--frames", type=int, help="override the number of frames")
    r.add_argument("-q", "--quiet", action="store_true", help="no progress line")
    r.add_argument("--deterministic", action="store_true",
                   help="leave the wall-clock timings (timings/ entities) out of the recording: the same scene "
                        "and seed then give recordings `rerun rrd compare` finds equal")
    r.set_defaults(func=cmd_run)
    v = sub.add_parser("validate", parents=[common], help="check a scene without running it")
    v.add_argument("scene")
    v.set_defaults(func=cmd_validate)
    b = sub.add_parser("bench", parents=[common], help="run the benchmarks (separate from the tests)")
    from pipeline.bench import BENCHES
    b.add_argument("which", nargs="*", default=["all"],
                   help=f"any of: {' '.join(BENCHES)} all (default: all)")
    b.add_argument("--json", help="also write the figures to this JSON file")
    b.set_defaults(func=cmd_bench)
    m = sub.add_parser("matrix", parents=[common], help="dress every garment kind on every character and tabulate the fit")
    m.add_argument("--frames", type=int, default=30, help="frames simulated per pair (default 30)")
    m.add_argument("--character", action="append", help="only this character (repeatable)")
    m.add_argument("--garment", action="append", help="only this garment kind (repeatable)")
    m.add_argument("--json", help="also write the figures to this JSON file")
    m.add_argument("-q", "--quiet", action="store_true", help="only the table")
    m.add_argument("--corpus", action="store_true",
                   help="every character and clip in the assets folder (GARMENT_ASSETS), each in minimal scenes that "
                        "start inside the clip with no tuning keys, run as a sweep; pass/fail against the targets")
    m.add_argument("--full", action="store_true", help="--corpus: every clip with every garment kind (default: "
                                                        "every clip once and every kind once, round-robin)")
    m.add_argument("-o", "--output", help="--corpus: folder for the sweep, its recordings and table (default sweeps/corpus)")
    m.add_argument("--jobs", type=int, help="--corpus: worker processes (default: every core)")
    m.add_argument("--pattern", action="append", help="--corpus: only this GarmentCode pattern of the assets' "
                                                      "garmentcode/ folder (file name without _specification.json; "
                                                      "repeatable; default: every one)")
    m.add_argument("--patterns", metavar="DIR", help="--corpus: the GarmentCode patterns of this folder "
                                                     "(*_specification.json, in subfolders or not) instead of the "
                                                     "assets' garmentcode/ folder")
    m.add_argument("--only-patterns", action="store_true", help="--corpus: the GarmentCode patterns, not the "
                                                                "built-in kinds")
    m.add_argument("--no-patterns", action="store_true", help="--corpus: the built-in kinds, not the GarmentCode "
                                                              "patterns")
    m.set_defaults(func=cmd_matrix)
    ex = sub.add_parser("export", parents=[common], help="write a recording's (or a scene run's) garments and body "
                                                         "as npz, pc2 (+ obj rest mesh), obj, glb or usd files")
    ex.add_argument("scene", metavar="RECORDING.rrd|SCENE.yaml", help="a .rrd recording, or a scene .yaml (run first, then exported with UVs)")
    ex.add_argument("--format", action="append", required=True,
                    help="npz | pc2 | obj | glb | usd (repeatable or comma-separated; usd needs the 'usd' extra)")
    ex.add_argument("-o", "--output", help="folder for the files (default: <recording stem>_export next to it)")
    ex.add_argument("--frames", type=int, help="a scene: override the number of frames")
    ex.add_argument("-q", "--quiet", action="store_true", help="a scene: no progress line")
    ex.set_defaults(func=cmd_export)
    sw = sub.add_parser("sweep", parents=[common], help="run a base scene once per combination of overrides (a grid "
                                                        "and/or cases) on a process pool or a Ray cluster; metrics "
                                                        "table as CSV and Parquet")
    sw.add_argument("scene", metavar="SWEEP.yaml", help="the sweep file (base scene, grid, cases; see scenes/sweep_example.yaml)")
    sw.add_argument("--jobs", type=int, help="worker processes (default: the sweep file's 'jobs', else every core)")
    sw.add_argument("--ray", nargs="?", const="", metavar="ADDRESS",
                    help="run the jobs as Ray tasks: on the cluster at ADDRESS, or on a local one when no address "
                         "is given (extra 'ray': pip install -e \".[ray]\")")
    sw.add_argument("--retry-failed", action="store_true", help="run the failed jobs of an earlier run again "
                                                                 "(finished ones are always skipped)")
    sw.add_argument("-o", "--output", help="results folder (default: the sweep file's 'output', else sweeps/<name>)")
    sw.add_argument("-q", "--quiet", action="store_true", help="no progress; only the summary")
    sw.set_defaults(func=cmd_sweep)
    ins = sub.add_parser("inspect", parents=[common], help="a character file as the pipeline reads it: joints, "
                                                           "clips, mesh size, up axis, garment anchors; or a "
                                                           "GarmentCode pattern: panels, stitches, edge kinds, size, "
                                                           "the body it was made for, and a PNG of the panels")
    ins.add_argument("asset", help="a .glb / .gltf / .bvh file, 'builtin' (the procedural character), or a "
                                   "GarmentCode *_specification.json")
    ins.add_argument("--json", action="store_true", help="print the facts as JSON")
    ins.add_argument("--png", help="a pattern's panels drawing (default: NAME_panels.png in the current folder)")
    ins.set_defaults(func=cmd_inspect)
    me = sub.add_parser("measure", parents=[common], help="a character's measurements as a GarmentCode body file "
                                                         "(body_measurements.yaml: cm, degrees)")
    me.add_argument("character", help="a .glb / .gltf / .bvh file, or 'builtin' (the procedural character)")
    me.add_argument("-o", "--out", help="write the body file here (default: print it)")
    me.set_defaults(func=cmd_measure)
    sn = sub.add_parser("snapshot", parents=[common], help="PNGs of a recording's scene view at chosen frames, through the Rerun "
                                         "viewer (headless; software Vulkan without a GPU)")
    sn.add_argument("recording", help="the .rrd file")
    sn.add_argument("--frames", default="0,45,-1", help="frame numbers on the timeline, comma-separated; -1 = last "
                                                        "(default 0,45,-1)")
    sn.add_argument("-o", "--out", default="snapshots", help="folder for the PNGs (default snapshots/)")
    sn.add_argument("--tab", help="a tab other than the opening one (rig, colliders, maps, garments, obstacles)")
    sn.add_argument("--turn", type=float, default=0.0, help="turn every 3D view's camera this many degrees about "
                    "its up axis round what it looks at (180: from behind; default 0)")
    sn.add_argument("--timeline", default="frame", help=argparse.SUPPRESS)
    sn.set_defaults(func=cmd_snapshot)
    return p


def _show_warning(message, category, filename, lineno, file=None, line=None):
    # a stage's warning is for the user (a repaired mesh, a released attachment): no source line
    print(f"warning: {message}", file=sys.stderr if file is None else file, flush=True)


def _one_line(text: str, limit: int = 600) -> str:
    line = " ".join(str(text).split())
    return line if len(line) <= limit else line[:limit - 3] + "..."


def _user_message(e: BaseException, scene: str | None) -> str:
    """The error's text on one line, prefixed with the scene file (and the item) when it lacks it."""
    from pipeline import where
    msg = _one_line(e)
    if scene and scene not in msg:
        now = where.current()
        item = f" {now['item']}:" if now["item"] else ""
        msg = f"{scene}: {now['stage']}:{item} {msg}"
    return msg


def _bug_message(e: BaseException, scene: str | None) -> str:
    from pipeline import where
    now = where.current()
    item = f" while processing {now['item']}" if now["item"] else ""
    detail = _one_line(f"{type(e).__name__}: {e}", 300)
    return (f"internal error in stage {now['stage']!r} of {scene or '<no scene>'}{item}: {detail} "
            f"(a bug, not your input; run again with --debug for the traceback)")


def main(argv: list[str] | None = None) -> int:
    import warnings

    from pipeline import where
    from pipeline.scene import MAX_FRAMES
    args = build_parser().parse_args(argv)
    scene = str(Path(args.scene)) if getattr(args, "scene", None) else None   # as load_scene names it
    where.reset(scene)
    if getattr(args, "jobs", None) is not None and args.jobs < 1:
        print(f"error: {scene + ': ' if scene else ''}--jobs: expected a positive integer, got {args.jobs}",
              file=sys.stderr)
        return EXIT_USAGE
    if isinstance(getattr(args, "frames", None), int) and not 1 <= args.frames <= MAX_FRAMES:   # snapshot's is a list
        print(f"error: {scene + ': ' if scene else ''}--frames: expected a positive integer up to {MAX_FRAMES:,}, "
              f"got {args.frames}", file=sys.stderr)
        return EXIT_USAGE
    shown, warnings.showwarning = warnings.showwarning, _show_warning
    _interrupted[0] = _terminated[0] = False
    installed = signal.getsignal(signal.SIGINT) is signal.default_int_handler   # not ignored (a background job)
    if installed:
        signal.signal(signal.SIGINT, _on_sigint)
    term = signal.getsignal(signal.SIGTERM) is signal.SIG_DFL
    if term:
        signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        return args.func(args)
    except _user_errors() as e:
        print(f"error: {_user_message(e, scene)}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        return _interrupted_exit()
    except Exception as e:   # last resort: a bug. One line, exit 1; the recording was not written
        if _interrupted[0]:   # a library turned the Ctrl-C into another error
            return _interrupted_exit()
        if getattr(args, "debug", False):
            import traceback
            traceback.print_exc()
        print(f"error: {_bug_message(e, scene)}", file=sys.stderr)
        return EXIT_BUG
    finally:
        warnings.showwarning = shown
        if term:
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
        handler = signal.getsignal(signal.SIGINT)
        if handler is _on_sigint or (handler is signal.SIG_IGN and installed and not _cli_process[0]):
            signal.signal(signal.SIGINT, signal.default_int_handler)   # called in-process: as found


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
