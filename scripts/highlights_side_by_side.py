"""The highlights stage of an earlier revision and the current one, side by side.

    mkdir before && git archive REV src/pcdof/stages/highlights | tar -x -C before
    python scripts/highlights_side_by_side.py before/src/pcdof/stages/highlights --repeats 21

(a revision from before the stage became a package: ``git show REV:src/pcdof/highlights.py > before.py`` and
pass ``before.py``.)

Frames: the benchmark's speed frames (synthetic portrait, 512x424 depth, the scene's default lens) at
--sizes; frames with many clipped blobs (the ``highlights`` scene and the wide benchmark's ``night`` and
``thin`` scenes, --many-size); and --random frames of every scene name and several seeds, checked for
equality only. Each frame goes through the pipeline once (default options: ``auto`` highlights) for its
colour and circle-of-confusion map, the stage's inputs. Timed: the part of the stage the pipeline waits for,
:func:`reconstruct_prepared` with method ``auto`` (its colour-only half, :func:`prepare_highlights`, runs
beside the fill; it is timed too, and each module reconstructs from its own). Both modules run in one
process, alternated per repeat (ABBA, so neither always goes first); medians in ms, their ratio, and whether
the two outputs are bit-identical (every frame, every repeat). --pipeline: also the whole pipeline on the speed
frames with each module in turn as ``pcdof.stages.highlights`` (the stage's record and the frame's time, and the
images).
"""

import argparse
import importlib.util
import os
import statistics
import sys
import time

import numpy as np


def load_before(path: str):
    """The highlights stage in *path*: a package folder, as ``pcdof.stages._highlights_before``, or an earlier
    single module, as ``pcdof._highlights_before`` (either way its relative imports are pcdof's)."""
    import pcdof.stages  # noqa: F401  (the parent packages of the module loaded)

    if os.path.isdir(path):
        spec = importlib.util.spec_from_file_location("pcdof.stages._highlights_before",
                                                      os.path.join(path, "__init__.py"),
                                                      submodule_search_locations=[path])
    else:
        spec = importlib.util.spec_from_file_location("pcdof._highlights_before", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def stage_inputs(sf):
    """(colour, CoC map) the pipeline's highlights stage gets for synthetic frame *sf* (its default lens)."""
    from pcdof import pipeline

    res = pipeline.run(sf.frame, sf.default_lens)
    return sf.frame.color, res.coc_px


def frames(args):
    """(group, name, colour, CoC) of every frame measured: "speed", "many" (timed) and "random" (checked)."""
    from pcdof.synth import SCENES, generate_scene
    from pcdof.synth.wide import generate_wide

    out = []
    for w, h in [tuple(int(v) for v in s.split("x")) for s in args.sizes.split(",")]:
        sf = generate_scene("portrait", color_size=(w, h), depth_size=(512, 424), seed=0)
        out.append(("speed", f"portrait {w}x{h}", *stage_inputs(sf)))
    w, h = (int(v) for v in args.many_size.split("x"))
    for seed in (0, 1):
        sf = generate_scene("highlights", color_size=(w, h), depth_size=(512, 424), seed=seed)
        out.append(("many", f"highlights {w}x{h} seed {seed}", *stage_inputs(sf)))
    for kind, seed in (("night", 1), ("night", 3), ("thin", 6)):
        sf, _ = generate_wide(kind, seed=seed, color_size=(w, h), depth_size=(512, 424))
        out.append(("many", f"wide {kind} {w}x{h} seed {seed}", *stage_inputs(sf)))
    sf, _ = generate_wide("night", seed=4, color_size=(1920, 1080), depth_size=(512, 424))
    out.append(("many", "wide night 1920x1080 seed 4", *stage_inputs(sf)))
    names = sorted(SCENES)
    for i in range(args.random):
        name, seed = names[i % len(names)], 100 + i
        size = ((640, 480), (320, 240), (1280, 720))[i % 3]
        sf = generate_scene(name, color_size=size, depth_size=(512, 424), seed=seed)
        out.append(("random", f"{name} {size[0]}x{size[1]} seed {seed}", *stage_inputs(sf)))
    for kind, seed in (("room", 11), ("thin", 12), ("night", 13)):
        sf, _ = generate_wide(kind, seed=seed, color_size=(320, 240), depth_size=(512, 424))
        out.append(("random", f"wide {kind} 320x240 seed {seed}", *stage_inputs(sf)))
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("before", help="an earlier src/pcdof/stages/highlights folder (or src/pcdof/highlights.py)")
    ap.add_argument("--repeats", type=int, default=21)
    ap.add_argument("--sizes", default="640x480,1920x1080")
    ap.add_argument("--many-size", default="640x480")
    ap.add_argument("--random", type=int, default=9, help="random frames checked for equality")
    ap.add_argument("--pipeline", action="store_true", help="also the whole pipeline with each module")
    args = ap.parse_args(argv)

    from pcdof.stages import highlights

    modules = {"before": load_before(args.before), "now": highlights}

    def reconstruct(module, color, coc):
        prepared = module.prepare_highlights(color)
        if prepared is None:
            return None, 0.0, 0.0
        t0 = time.perf_counter()
        prepared = module.prepare_highlights(color)
        t1 = time.perf_counter()
        out = module.reconstruct_prepared(prepared, method="auto", coc_px=coc)
        return out, t1 - t0, time.perf_counter() - t1

    print(f"{'frame':34s} {'blobs':>5s}  {'reconstruct ms before / now = ratio':>36s}  {'prepare ms b / n':>16s}  same")
    all_same = True
    for group, name, color, coc in frames(args):
        prepared = highlights.prepare_highlights(color)
        blobs = 0 if prepared is None else len(prepared.found.boxes)
        repeats = args.repeats if group != "random" else 3
        ts = {k: ([], []) for k in modules}
        same = True
        for i in range(repeats):
            outs = {}
            for k, module in list(modules.items())[:: 1 if i % 2 == 0 else -1]:
                outs[k], prep, rec = reconstruct(module, color, coc)
                ts[k][0].append(rec)
                ts[k][1].append(prep)
            same &= (outs["before"] is None and outs["now"] is None) or np.array_equal(outs["before"], outs["now"])
        all_same &= same
        med = {k: [statistics.median(v) * 1e3 for v in ts[k]] for k in modules}
        b, n = med["before"][0], med["now"][0]
        ratio = f"{b / n:5.2f}x" if n > 0 else "   -  "
        print(f"{name:34s} {blobs:5d}  {b:14.3f} / {n:7.3f} = {ratio}  {med['before'][1]:7.3f} / {med['now'][1]:6.3f}"
              f"  {'yes' if same else 'NO'}{'' if group != 'random' else ' (checked)'}")
    print("every output bit-identical:", "yes" if all_same else "NO")
    if args.pipeline:
        pipeline_side_by_side(modules, args)


def pipeline_side_by_side(modules, args) -> None:
    """The whole pipeline on the speed frames with each module as ``pcdof.stages.highlights`` (the pipeline imports
    the stage's functions when it runs it), alternated per repeat: the highlights record's ms, the frame's ms and
    whether the images are bit-identical."""
    from pcdof import pipeline
    from pcdof.synth import generate_scene

    name = "pcdof.stages.highlights"
    print(f"\npipeline (medians of {args.repeats}): highlights stage ms before / now = ratio; frame ms before / now")
    for w, h in [tuple(int(v) for v in s.split("x")) for s in args.sizes.split(",")]:
        sf = generate_scene("portrait", color_size=(w, h), depth_size=(512, 424), seed=0)
        ts = {k: ([], []) for k in modules}
        images = {}
        try:
            for i in range(args.repeats + 1):
                for k, module in list(modules.items())[:: 1 if i % 2 == 0 else -1]:
                    sys.modules[name] = module
                    t0 = time.perf_counter()
                    res = pipeline.run(sf.frame, sf.default_lens)
                    took = time.perf_counter() - t0
                    images[k] = res.image
                    if i:  # (the first: warm-up)
                        ts[k][0].append(next(t.seconds for t in res.trace if t.name == "highlights"))
                        ts[k][1].append(took)
                same = np.array_equal(images["before"], images["now"])
        finally:
            sys.modules[name] = modules["now"]
        (sb, fb), (sn, fn) = ([statistics.median(v) * 1e3 for v in ts[k]] for k in ("before", "now"))
        print(f"portrait {w}x{h}: {sb:.3f} / {sn:.3f} = {sb / sn:.2f}x; {fb:.1f} / {fn:.1f}; "
              f"{'bit-identical' if same else 'DIFFERENT'}")


if __name__ == "__main__":
    from pcdof.runtime.process import tune_process

    tune_process()  # timed in a process tuned as the pcdof command tunes its own
    main()
