"""``biomotion data``: the dataset registry — build the cached training set, augment it, list the sources
(`biomotion.data.registry`, `biomotion.data.augment`, `biomotion.data.sources`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from biomotion.cli._common import add_data_root, add_overwrite, command_line, fresh_folder, number


def add_parser(verbs) -> None:
    data = verbs.add_parser(
        "data",
        help="build and inspect the cached training set",
        description="The dataset registry: every source under a data root mapped onto the "
        "canonical Rajagopal 2016 coordinates, one rate, subject-level splits. "
        "Python: biomotion.build_cache, biomotion.DatasetCache.",
    )
    actions = data.add_subparsers(dest="data_verb", metavar="ACTION", required=True)
    build = actions.add_parser(
        "build",
        help="build the cache (clips.safetensors + manifest.json)",
        description="Read every registered source present under --data-root, resample to --rate with an "
        "anti-alias filter, map coordinates by name onto Rajagopal 2016 (masks for absent ones), and "
        "write clips.safetensors and manifest.json (counts per source, subject, action; splits).",
    )
    add_data_root(build)
    build.add_argument("--out", type=Path, required=True, help="cache folder to write (new or empty)")
    add_overwrite(build)
    build.add_argument("--rate", type=number(1, 1000), default=30.0, help="common rate in Hz (default: %(default)s)")
    build.add_argument("--source", action="append", help="only this source (repeatable); default: all present")
    build.add_argument("--report", type=Path, help="also write the counts as a Markdown table (docs/results/)")
    build.add_argument("--quiet", action="store_true", help="no progress bar")
    build.set_defaults(run=_build)
    augment = actions.add_parser(
        "augment",
        help="add time-warped and posture-offset copies of the training clips (for the muscle surrogate)",
        description="Copy a cache and append its training-split clips played faster or slower (--time-warp "
        "factors; 1.25 = 25 % faster), resampled at the cache rate, and with random marker-placement "
        "posture offsets (--posture-copies: pelvis turned, thighs and trunk kept, hip axial rotation "
        "offset; see biomotion.data.posture). Validation and test clips are left as they are. Label the "
        "result with `biomotion train labels` and train the surrogate on it (see biomotion.data.augment).",
    )
    augment.add_argument("--cache", type=Path, required=True, help="cache folder from `biomotion data build`")
    augment.add_argument("--out", type=Path, required=True, help="new cache folder to write (new or empty)")
    add_overwrite(augment)
    augment.add_argument(
        "--time-warp",
        type=number(0.1, 10),
        nargs="*",
        default=[0.8, 0.9, 1.1, 1.25],
        metavar="F",
        help="speed factors of the copies; none for no time-warped copies (default: %(default)s)",
    )
    augment.add_argument(
        "--posture-copies",
        type=number(0, 100, integer=True),
        default=0,
        metavar="N",
        help="posture-offset copies per clip (default: %(default)s)",
    )
    augment.add_argument(
        "--seed",
        type=number(0, 2**63 - 1, integer=True),
        default=0,
        help="seed of the posture offsets (default: %(default)s)",
    )
    add_data_root(augment, "data root holding the canonical model, for posture copies")
    augment.add_argument(
        "--split",
        default="train",
        choices=("train", "val", "test"),
        help="split whose clips are copied (default: %(default)s)",
    )
    augment.add_argument(
        "--source",
        action="append",
        metavar="NAME",
        help="copy only the clips of this source (repeatable; default: every source); the other "
        "sources' clips are kept without copies",
    )
    augment.add_argument("--quiet", action="store_true", help="no progress bar")
    augment.set_defaults(run=_augment)
    sources = actions.add_parser("sources", help="list registered sources and whether the data root has them")
    add_data_root(sources)
    sources.set_defaults(run=_sources)


def _build(args: argparse.Namespace) -> int:
    from biomotion.data.registry import build_cache, manifest_markdown
    from biomotion.errors import ConfigError
    from biomotion.io.atomic import atomic_write

    if not args.data_root.is_dir():
        raise ConfigError(f"{args.data_root}: --data-root is not a folder")
    with fresh_folder(args.out, args.overwrite) as scratch:
        manifest = build_cache(
            args.data_root, scratch, rate=args.rate, sources=args.source or None, progress=not args.quiet
        )
    counts = manifest["counts"]
    print(
        f"cached {counts['clips']} clips ({counts['frames']} frames at {manifest['rate_hz']:g} Hz) "
        f"from {len(counts['per_source'])} sources in {manifest['build_seconds']:.1f} s -> {args.out}"
    )
    for source, n in counts["per_source"].items():
        print(f"  {source:10s} {n:5d} clips  {counts['subjects_per_source'][source]:3d} subjects")
    print(f"  splits: {counts['per_split']}")
    for skipped in manifest["skipped_sources"]:
        print(f"  skipped {skipped}")
    if args.report:
        with atomic_write(args.report) as handle:
            handle.write(manifest_markdown(manifest, command_line()))
        print(f"  counts written to {args.report}")
    return 0


def _augment(args: argparse.Namespace) -> int:
    from biomotion.data.augment import augmented_cache

    model = None
    if args.posture_copies > 0:
        from biomotion.data.clips import body_model

        model = body_model(args.data_root)
    with fresh_folder(args.out, args.overwrite) as scratch:
        manifest = augmented_cache(
            args.cache,
            scratch,
            args.time_warp,
            posture_copies=args.posture_copies,
            model=model,
            seed=args.seed,
            split=args.split,
            sources=args.source or (),
            progress=not args.quiet,
        )
    counts = manifest["counts"]
    kinds = [f"time-warped x{', x'.join(f'{f:g}' for f in args.time_warp)}"] if args.time_warp else []
    kinds += [f"{args.posture_copies} posture offset(s) each"] if args.posture_copies > 0 else []
    print(
        f"wrote {counts['clips']} clips ({manifest['augmentation']['copies']} copies of the {args.split} split: "
        f"{'; '.join(kinds)}) in {manifest['build_seconds']:.1f} s -> {args.out}"
    )
    return 0


def _sources(args: argparse.Namespace) -> int:
    from biomotion.data.sources import SOURCES
    from biomotion.errors import ConfigError

    if not args.data_root.is_dir():  # a typo would list every source as absent
        raise ConfigError(f"{args.data_root}: --data-root is not a folder")
    for source in SOURCES.values():
        state = "present" if source.present(args.data_root) else "absent"
        print(f"{source.name:12s} {source.folder + '/':26s} {state:8s} {source.description}")
    return 0
