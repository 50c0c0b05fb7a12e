"""``biomotion train``: fit every learned part of biomotion from data (`biomotion.training`), each writing its
weights with a model card that records this very command, the data and the metrics.

The shipped checkpoints were made by the commands on their cards (``checkpoints/*.md``); the order is
``data build`` → ``train tokenizer`` → ``train generator`` (and ``--population``), and ``train labels`` →
``train surrogate`` for the muscle surrogate.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from biomotion.cli._common import add_data_root, command_line, number, writable_file

FITTING = (
    "training time and iterations: training stops at whichever of --minutes and --iterations comes first; "
    "the seed fixes data order and initialisation"
)


def add_parser(verbs) -> None:
    train = verbs.add_parser(
        "train",
        help="train the tokenizer, generator, muscle surrogate and learned ground forces; label the cache; "
        "fit muscle paths and ANSUR segment lines",
        description="Fit biomotion's learned parts from data. Each writes .safetensors weights "
        "and a model card (.json, .md) beside them. " + FITTING,
    )
    models = train.add_subparsers(dest="train_verb", metavar="MODEL", required=True)

    tokenizer = models.add_parser(
        "tokenizer",
        help="the motion tokenizer (PG-BIG Sec. 3.1 VQ-VAE)",
        description="Train the motion tokenizer on a dataset cache (`biomotion data build`)."
        " Python: biomotion.training.train_tokenizer.train.",
    )
    _common(tokenizer)
    tokenizer.set_defaults(run=_tokenizer)

    generator = models.add_parser(
        "generator",
        help="the profile-action prior with its subject profiler (PG-BIG Sec. 3.2, A.6)",
        description="Train the prior over tokenizer codes, conditioned on the profile and "
        "the action, on a dataset cache. Python: "
        "biomotion.training.train_generator.train.",
    )
    _common(generator)
    generator.add_argument("--tokenizer", type=Path, required=True, help="trained tokenizer .safetensors")
    generator.add_argument("--population", action="store_true", help="train the action-only baseline prior")
    generator.add_argument(
        "--statistics-only",
        action="store_true",
        help="recompute the per-action statistics of the trained --out from --cache, keeping its "
        "weights (--tokenizer is then not read)",
    )
    generator.set_defaults(run=_generator)

    surrogate = models.add_parser(
        "surrogate",
        help="the muscle-activation surrogate (PG-BIG Sec. 3.3, A.8)",
        description="Train the surrogate on static-optimization labels of a cache "
        "(`biomotion train labels`). Python: "
        "biomotion.training.train_surrogate.train.",
    )
    _common(surrogate)
    surrogate.add_argument("--labels", type=Path, help="labels file (default: <cache>/surrogate_labels.safetensors)")
    surrogate.add_argument(
        "--threads",
        type=number(1, 256, integer=True),
        default=1,
        help="torch CPU threads for training (default: %(default)s)",
    )
    surrogate.set_defaults(run=_surrogate)

    labels = models.add_parser(
        "labels",
        help="static-optimization activations (80 Rajagopal muscles) and COM terms for every cached clip",
        description="For every clip of the cache: inverse dynamics on the generic Rajagopal 2016 model with the "
        "ground reaction inferred from the motion, batched static optimization (squared activations, "
        "the model's Millard 2012 muscles, reserves), and the whole-body COM position, velocity and "
        "acceleration. Writes <cache>/surrogate_labels.safetensors and bounds_muscle_activations.json. "
        "Each finished clip is kept beside the output until all are done, so an interrupted run "
        "resumes; labels already made from this very cache are reused. Python: "
        "biomotion.training.surrogate_labels.labels_for_cache.",
    )
    labels.add_argument("--cache", type=Path, required=True, help="cache folder from `biomotion data build`")
    add_data_root(labels, "folder holding opensim-models/ (the Rajagopal model)")
    labels.add_argument("--out", type=Path, help="labels file (default: <cache>/surrogate_labels.safetensors)")
    labels.add_argument("--quiet", action="store_true", help="no progress bar")
    labels.set_defaults(run=_labels)

    paths = models.add_parser(
        "paths",
        help="muscle path functions fitted to OpenSim's geometry of a model (needs opensim)",
        description="Sample OpenSim's musculotendon lengths and moment arms of MODEL at random poses and fit one "
        "polynomial (or a gated piecewise one) per muscle; `biomotion analyze --muscles` uses the file. "
        "Minutes per model. Python: biomotion.training.fit_paths.fit_paths.",
    )
    paths.add_argument("--model", type=Path, required=True, help=".osim model")
    paths.add_argument("--out", type=Path, required=True, help="output .safetensors")
    paths.add_argument(
        "--samples",
        type=number(100, 10**6, integer=True),
        default=6000,
        help="training poses (plus 25%% held out) (default: %(default)s)",
    )
    paths.add_argument("--seed", type=number(0, 2**63 - 1, integer=True), default=0)
    paths.add_argument(
        "--range",
        action="append",
        default=[],
        metavar="COORD=LO:HI",
        help="sample COORD in [LO, HI] (rad or m) instead of its model range",
    )
    paths.set_defaults(run=_paths)

    segments = models.add_parser(
        "segments",
        help="the ANSUR II segment-length lines that scale a model to a person's measures",
        description="Least-squares line of each segment's length against stature over the ANSUR II men; writes the "
        "JSON that biomotion.body.scaling.segments ships. Python: "
        "biomotion.training.fit_segments.fit_lines.",
    )
    add_data_root(segments, "folder holding anthropometry/ANSUR_II_MALE_Public.csv")
    segments.add_argument("--out", type=Path, required=True, help="output .json")
    segments.set_defaults(run=_segments)

    forces = models.add_parser(
        "ground-forces",
        help="the learned ground reaction (GRF and CoP from kinematics), supervised by force plates",
        description="Train the network that corrects m(g + a_COM) into per-foot ground forces and centres of "
        "pressure from the kinematics, on every Fukuchi treadmill trial with its force plate under --data-root "
        "(analysed once and cached under ~/.cache/biomotion/ground_forces). Minutes on one CPU thread; fixed "
        "iterations and seed. Held-out figures: `biomotion eval ground-forces`. "
        "Python: biomotion.training.train_ground_forces.train.",
    )
    forces.add_argument("--config", type=Path, required=True, help="YAML config (configs/ground_forces.yaml)")
    add_data_root(forces, "folder with fukuchi-running/ (runners with running C3D, model and IK)")
    forces.add_argument("--out", type=Path, required=True, help="weights file to write (.safetensors)")
    forces.add_argument(
        "--exclude-subjects",
        nargs="+",
        default=[],
        metavar="RUNNER",
        help="runners to leave out of training (e.g. RBDS001), to score them held out",
    )
    forces.add_argument("--iterations", type=number(1, integer=True), help="override the config's train.iterations")
    forces.add_argument(
        "--seed", type=number(0, 2**63 - 1, integer=True), default=0, help="random seed (default: %(default)s)"
    )
    forces.add_argument("--quiet", action="store_true", help="no progress lines")
    forces.set_defaults(run=_ground_forces)

    refiner = models.add_parser(
        "refiner",
        help="the PhysPT refiner (noisy motion -> physically consistent motion, torques, contact forces)",
        description="Train the PhysPT refiner self-supervised on a dataset cache (`biomotion data build`): real "
        "clips corrupted like markerless capture (jitter, drift, foot sliding, root bounce, dropped frames) "
        "must come back clean, with force, contact and Euler-Lagrange losses through the body model (Zhang et "
        "al. 2024, Sec. 3.2). Fixed iterations and seed; the contact QP of every clean clip is computed once "
        "and cached under ~/.cache/biomotion/refiner. Python: biomotion.training.train_refiner.train.",
    )
    _model_args(
        refiner, "refiner.yaml", "folder with opensim-models/ (the canonical Rajagopal model)", quiet="no progress bar"
    )
    refiner.add_argument(
        "--threads",
        type=number(1, 256, integer=True),
        help="torch CPU threads (default: the config's train.threads); results depend on it only by rounding",
    )
    refiner.set_defaults(run=_refiner)

    evaluator = models.add_parser(
        "evaluator",
        help="the motion-text evaluator of the distribution metrics (FID, R-precision; T2M-style)",
        description="Train the contrastive motion and text encoders (T2M, Guo et al. 2022, Sec. 5) behind FID, "
        "R-precision, diversity and multimodality on the training split of a dataset cache only (no val or test "
        "subject is read for training); texts through the offline MiniLM encoder. Fixed iterations and seed; "
        "minutes on one CPU thread. Python: biomotion.training.train_evaluator.train.",
    )
    _model_args(evaluator, "evaluator.yaml")
    evaluator.add_argument(
        "--threads",
        type=number(1, 256, integer=True),
        default=1,
        help="torch CPU threads for training (default: %(default)s)",
    )
    evaluator.set_defaults(run=_evaluator)

    adapter = models.add_parser(
        "shape-adapter",
        help="the shape-conditioned motion c-VAE (HUMOS-style: a gait moved onto another body)",
        description="Train the shape adapter on the gait clips of the training split of a dataset cache (Fukuchi, "
        "Schreiber-Moissenet, Hamner; OpenCap kept out), each subject with the Shape of its own scaled model under "
        "--data-root, without paired data: reconstruction with the own shape, cycle consistency A -> B -> A and a "
        "foot-sliding term by forward kinematics (HUMOS Sec. 3). Fixed iterations and seed; minutes on one CPU "
        "thread. Python: biomotion.training.train_shape_vae.train.",
    )
    _model_args(
        adapter, "shape_adapter.yaml", "folder with the subjects' scaled models (fukuchi-running/, Hamner2013/, ...)"
    )
    adapter.add_argument(
        "--threads", type=number(1, 256, integer=True), default=1, help="torch CPU threads (default: %(default)s)"
    )
    adapter.set_defaults(run=_shape_adapter)

    flexmotion = models.add_parser(
        "flexmotion",
        help="FlexMotion: multimodal autoencoder + latent diffusion (motion with its torques, GRF, activations)",
        description="Build (or read) the multimodal windows of the training split (coordinates, velocities, "
        "torques by inverse dynamics with the contact solve's ground reaction, activations of the muscle "
        "surrogate), train the physics-aware autoencoder (reconstruction + Euler-Lagrange term) and then the "
        "text- and profile-conditioned latent diffusion (FlexMotion Sec. 3). Fixed iterations and seed. Python: "
        "biomotion.training.train_flexmotion.train.",
    )
    _model_args(
        flexmotion, "flexmotion.yaml", "folder with opensim-models/ (the canonical Rajagopal model)", iterations=False
    )
    flexmotion.add_argument(
        "--surrogate",
        type=Path,
        default=Path("checkpoints/surrogate.safetensors"),
        help="muscle surrogate giving the activations (default: %(default)s)",
    )
    flexmotion.set_defaults(run=_flexmotion)

    control_net = models.add_parser(
        "control-net",
        help="FlexMotion's control module: a ControlNet over the frozen FlexMotion (joint paths, GRF, torques, "
        "activations)",
        description="Train FlexMotion's spatial control module (FlexMotion Sec. 3.3) over the shipped FlexMotion "
        "(the config's `flexmotion`, frozen): a trainable copy of the latent denoiser between zero-initialised "
        "linears, fed control targets drawn from the training windows' own modalities (body origins, vertical GRF, "
        "a joint moment, an activation, a coordinate; dense and sparse in time). Fixed iterations and seed. "
        "Python: biomotion.training.train_control_net.train.",
    )
    _model_args(
        control_net, "control_net.yaml", "folder with opensim-models/ (the canonical Rajagopal model)", iterations=False
    )
    control_net.set_defaults(run=_control_net)


def _model_args(
    parser: argparse.ArgumentParser,
    config: str,
    data_root: str | None = None,
    iterations: bool = True,
    quiet: str = "no progress lines",
) -> None:
    """--config, --cache, --out, (--data-root), (--iterations), --seed and --quiet: what every model's training
    takes; each subcommand adds its own options after them."""
    parser.add_argument("--config", type=Path, required=True, help=f"YAML training config (configs/{config})")
    parser.add_argument("--cache", type=Path, required=True, help="cache folder from `biomotion data build`")
    parser.add_argument("--out", type=Path, required=True, help="weights file to write (.safetensors)")
    if data_root is not None:
        add_data_root(parser, data_root)
    if iterations:
        parser.add_argument("--iterations", type=number(1, integer=True), help="override the config's train.iterations")
    parser.add_argument(
        "--seed", type=number(0, 2**63 - 1, integer=True), default=0, help="random seed (default: %(default)s)"
    )
    parser.add_argument("--quiet", action="store_true", help=quiet)


def _common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", type=Path, required=True, help="YAML training config (configs/)")
    parser.add_argument("--cache", type=Path, required=True, help="cache folder from `biomotion data build`")
    parser.add_argument("--out", type=Path, required=True, help="weights file to write (.safetensors)")
    add_data_root(parser, "folder with opensim-models/ (the canonical Rajagopal model)")
    parser.add_argument("--minutes", type=number(0, low_open=True), help="stop after this much training time")
    parser.add_argument("--iterations", type=number(1, integer=True), help="override the config's train.iterations")
    parser.add_argument(
        "--seed", type=number(0, 2**63 - 1, integer=True), default=0, help="random seed (default: %(default)s)"
    )


def _config(args: argparse.Namespace) -> dict:
    """The YAML config, or a one-line error naming the file and line."""
    from biomotion.errors import ConfigError
    from biomotion.io.mappings import read_mapping

    if not args.config.is_file():
        raise ConfigError(f"{args.config}: --config is not a file")
    config = read_mapping(args.config, "training config", "a training config is a mapping (model:, data:, train: ...)")
    writable_file(args.out)
    return config


def _tokenizer(args: argparse.Namespace) -> int:
    import json

    from biomotion.training.train_tokenizer import train

    card = train(
        _config(args),
        args.cache,
        args.out,
        data_root=args.data_root,
        minutes=args.minutes,
        iterations=args.iterations,
        seed=args.seed,
        command=command_line(),
    )
    print(json.dumps({"before": card["metrics_val_before"], "after": card["metrics_val"]}, indent=1))
    return 0


def _generator(args: argparse.Namespace) -> int:
    import json

    from biomotion.io.tensors import read_metadata
    from biomotion.training.train_generator import refresh_statistics, train

    config = _config(args)
    if args.statistics_only:
        card = refresh_statistics(config, args.cache, args.data_root, args.out, command=command_line())
        print(f"{args.out}: statistics recomputed, SHA-256 {card['sha256']}")
        return 0
    read_metadata(args.tokenizer, "tokenizer weights")  # a wrong file fails now, not after the cache is read
    card = train(
        config,
        args.cache,
        args.tokenizer,
        args.data_root,
        args.out,
        population=args.population,
        minutes=args.minutes,
        iterations=args.iterations,
        seed=args.seed,
        command=command_line(),
    )
    print(json.dumps({"held_out": card["metrics_held_out"], "train": card["metrics_train"]}, indent=1))
    return 0


def _surrogate(args: argparse.Namespace) -> int:
    import json

    from biomotion.body.kinematics import torch_threads
    from biomotion.io.tensors import read_metadata
    from biomotion.training.train_surrogate import train

    config = _config(args)
    if args.labels is not None:  # a wrong file fails now, not after the cache is read
        read_metadata(args.labels, "surrogate labels")
    with torch_threads(args.threads):
        card = train(
            config,
            args.cache,
            args.out,
            data_root=args.data_root,
            labels_path=args.labels,
            minutes=args.minutes,
            iterations=args.iterations,
            seed=args.seed,
            command=command_line(),
        )
    print(
        json.dumps(
            {
                "val": {k: v for k, v in card["metrics_val"].items() if k != "per_muscle_r2"},
                "speed_3s_clip": card["speed_3s_clip"],
            },
            indent=1,
        )
    )
    return 0


def _labels(args: argparse.Namespace) -> int:
    from biomotion.data.registry import DatasetCache
    from biomotion.training.surrogate_labels import DEFAULT_NAME, labels_for_cache

    cache = DatasetCache(args.cache)
    out = args.out or Path(args.cache) / DEFAULT_NAME
    writable_file(out)
    labels = labels_for_cache(cache, args.data_root, out, progress=not args.quiet)
    info = labels.info
    print(
        f"labelled {info['clips']} clips ({info['frames']} frames; {info.get('clips_resumed', 0)} resumed) with "
        f"{info['muscle_curves']} muscles: converged {100 * info['converged_share']:.1f} % of frames, reserve RMS "
        f"{info['reserve_rms_nm']:.2f} N·m -> {out}"
    )
    return 0


def _paths(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from biomotion.training.fit_paths import fit_paths, parse_range

    writable_file(args.out)
    ranges = dict(parse_range(text) for text in args.range)
    paths = fit_paths(args.model, args.samples, args.seed, ranges, log=tqdm.write)
    paths.save(args.out)
    info = paths.info
    print(
        f"{paths.n_muscles} muscles, {len(paths.groups)} groups; worst held-out moment-arm RMSE "
        f"{info['worst_held_out_moment_arm_rmse_m'] * 1000:.3f} mm ({info['fit_seconds']} s) -> {args.out}"
    )
    return 0


def _segments(args: argparse.Namespace) -> int:
    import json

    from biomotion.body.scaling.segments import ANSUR_MEN
    from biomotion.io.atomic import atomic_write
    from biomotion.training.fit_segments import fit_lines

    writable_file(args.out)
    with atomic_write(args.out) as handle:
        json.dump(fit_lines(args.data_root / ANSUR_MEN), handle, indent=1)
        handle.write("\n")
    print(f"wrote {args.out}")
    return 0


def _ground_forces(args: argparse.Namespace) -> int:
    import json

    from biomotion.training.train_ground_forces import train

    config = _config(args)
    card = train(
        config,
        args.data_root,
        args.out,
        exclude_subjects=args.exclude_subjects,
        iterations=args.iterations,
        seed=args.seed,
        command=command_line(),
        log=None if args.quiet else print,
    )
    print(json.dumps({"train_frames": card["data"]["frames"], "fit_on_training_frames": card["metrics_train"]}))
    for line in card["data"]["skipped"]:
        print(f"  skipped {line}")
    print(f"{args.out}: SHA-256 {card['sha256']} (card {args.out.with_suffix('.md')})")
    return 0


def _refiner(args: argparse.Namespace) -> int:
    import json

    from biomotion.training.train_refiner import train

    config = _config(args)
    card = train(
        config,
        args.cache,
        args.out,
        data_root=args.data_root,
        iterations=args.iterations,
        seed=args.seed,
        threads=args.threads,
        progress=not args.quiet,
        command=command_line(),
    )
    print(json.dumps({"val": card["val"]["means"], "lowpass_cutoff_hz": card["val"]["lowpass_cutoff_hz"]}, indent=1))
    return 0


def _evaluator(args: argparse.Namespace) -> int:
    import json

    from biomotion.body.kinematics import torch_threads
    from biomotion.training.train_evaluator import train

    config = _config(args)
    with torch_threads(args.threads):
        card = train(
            config,
            args.cache.expanduser(),  # a card's command quotes "~/..." (`command_line`): it still runs as shown
            args.out,
            iterations=args.iterations,
            seed=args.seed,
            progress=not args.quiet,
            command=command_line(),
        )
    print(
        json.dumps({"held_out": card["figures_held_out"], "fid_held_out_halves": card["fid_held_out_halves"]}, indent=1)
    )
    print(f"{args.out}: SHA-256 {card['sha256']} (card {args.out.with_suffix('.md')})")
    return 0


def _shape_adapter(args: argparse.Namespace) -> int:
    import json

    from biomotion.training.train_shape_vae import train

    config = _config(args)
    card = train(
        config,
        args.cache.expanduser(),
        args.out,
        data_root=args.data_root,
        iterations=args.iterations,
        seed=args.seed,
        threads=args.threads,
        progress=not args.quiet,
        command=command_line(),
    )
    print(json.dumps(card["figures_training_subjects"], indent=1))
    print(f"{args.out}: SHA-256 {card['sha256']} (card {args.out.with_suffix('.md')})")
    return 0


def _flexmotion(args: argparse.Namespace) -> int:
    from biomotion.errors import ConfigError
    from biomotion.training.train_flexmotion import train

    config = _config(args)
    if not args.surrogate.is_file():
        raise ConfigError(f"{args.surrogate}: --surrogate is not a file")
    card = train(
        config,
        args.cache.expanduser(),
        args.out,
        data_root=args.data_root,
        surrogate=args.surrogate,
        seed=args.seed,
        progress=not args.quiet,
        command=command_line(),
    )
    print(f"{args.out}: SHA-256 {card['sha256']} (card {args.out.with_suffix('.md')}); seconds {card['seconds']}")
    return 0


def _control_net(args: argparse.Namespace) -> int:
    from biomotion.training.train_control_net import train

    card = train(
        _config(args),
        args.cache.expanduser(),
        args.out,
        data_root=args.data_root,
        seed=args.seed,
        progress=not args.quiet,
        command=command_line(),
    )
    print(f"{args.out}: SHA-256 {card['sha256']} (card {args.out.with_suffix('.md')}); seconds {card['seconds']}")
    return 0
