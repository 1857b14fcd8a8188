"""``elastic-gym benchmark``: one entry's scorecard on the versioned suite; a card verified
by re-running it; format 1 cards upgraded; the leaderboard rebuilt from scorecards."""

from __future__ import annotations

import argparse

from elastic_gym.cli.common import require_rl_extra
from elastic_gym.runtime.parallel import BACKENDS, DEFAULT_BACKEND


def add_parser(subcommands: argparse._SubParsersAction) -> None:
    from elastic_gym.benchmark.command import add_entry_options

    parser = subcommands.add_parser(
        "benchmark",
        help="score a controller + state source, a user's class or a trained policy on the "
        "elastic-gym benchmark suite; verify a scorecard; rebuild the leaderboard",
        description="Run the versioned benchmark suite (elastic-gym-v2: tasks x perturbation "
        "categories x robots x 10 published seeds) with one entry and write its scorecard "
        "(JSON, markdown, PNG); re-run a scorecard's entry and compare (--verify); or "
        "rebuild the leaderboard page, CSV and figure from scorecard files (--leaderboard).",
    )
    add_entry_options(parser)
    parser.add_argument(
        "--leaderboard",
        action="store_true",
        help="rebuild the leaderboard from the cards in --scorecards: the page --page, the "
        "CSV --csv and the figure --figure, nothing else; a file there that an earlier "
        "rebuild did not write is replaced only with --overwrite",
    )
    parser.add_argument(
        "--verify",
        metavar="CARD",
        help="re-run the command a scorecard records (it imports the classes it names) and "
        "report whether it reproduces the card's episodes and scores: bit for bit, or on "
        "another machine every status and every score within 1e-3; exit 1 if not",
    )
    parser.add_argument(
        "--exact",
        action="store_true",
        help="with --verify: exit 1 unless bit for bit (on a machine like the card's)",
    )
    parser.add_argument(
        "--upgrade",
        nargs="+",
        metavar="CARD",
        help="rewrite format 1 scorecards in the current format, in place (their scores "
        "recomputed and checked)",
    )
    parser.add_argument(
        "--output",
        metavar="DIR",
        help="default: ./benchmark_out/<label>; with --verify: the re-run's folder "
        "(default: a temporary one, removed)",
    )
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace an earlier scorecard (or, with --leaderboard, files the rebuild did "
        "not write)",
    )
    parser.add_argument(
        "--rescore",
        action="store_true",
        help="score the runs of an earlier benchmark of this entry (runs/runs.csv in "
        "--output, e.g. after the disk filled while the card was written) instead of "
        "running them",
    )
    parser.add_argument("--workers", type=int, help="parallel workers (default: one per CPU)")
    parser.add_argument("--backend", choices=BACKENDS, default=DEFAULT_BACKEND)
    parser.add_argument(
        "--scorecards",
        metavar="DIR",
        default="docs/leaderboard/scorecards",
        help="with --leaderboard: the scorecard folder (a notes.md beside it goes under "
        "the tables)",
    )
    parser.add_argument(
        "--page", metavar="MD", default="docs/leaderboard.md", help="with --leaderboard"
    )
    parser.add_argument(
        "--csv",
        metavar="CSV",
        help="with --leaderboard (default: leaderboard.csv in the folder named like the "
        "page, docs/leaderboard/ for docs/leaderboard.md)",
    )
    parser.add_argument(
        "--figure",
        metavar="PNG",
        help="with --leaderboard (default: leaderboard.png in the folder named like the page)",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.set_defaults(handler=run_benchmark_command)


def run_benchmark_command(args: argparse.Namespace) -> int:
    from elastic_gym.benchmark.command import entry_arguments
    from elastic_gym.benchmark.suite import DEFAULT_SUITE

    arguments = entry_arguments(
        args, leaderboard=args.leaderboard, verify=args.verify, upgrade=args.upgrade
    )
    if arguments.leaderboard:
        return _leaderboard(args)
    if arguments.upgrade:
        return _upgrade(args)
    if args.exact and not arguments.verify:
        raise ValueError("--exact applies to --verify only")
    if arguments.verify:
        return _verify(args)
    from elastic_gym.benchmark import run_benchmark

    if args.run and args.trust_pickle and not args.rescore:
        require_rl_extra("benchmark --run RUN --trust-pickle")
    run_benchmark(
        arguments.entry(),
        suite=args.suite or DEFAULT_SUITE,
        robots=args.robot,
        output_dir=args.output,
        workers=args.workers,
        backend=args.backend,
        progress=not args.no_progress,
        overwrite=args.overwrite,
        rescore=args.rescore,
    )
    return 0


def _leaderboard(args: argparse.Namespace) -> int:
    from elastic_gym.benchmark import rebuild_leaderboard
    from elastic_gym.benchmark.suite import DEFAULT_SUITE

    files, notes = rebuild_leaderboard(
        args.scorecards,
        args.page,
        args.suite or DEFAULT_SUITE,
        args.csv,
        args.figure,
        args.overwrite,
    )
    for note in notes:
        print(f"note: {note}")
    print("written: " + ", ".join(str(f) for f in files))
    return 0


def _upgrade(args: argparse.Namespace) -> int:
    from elastic_gym.benchmark.card import card_text
    from elastic_gym.benchmark.upgrade import upgrade_file
    from elastic_gym.runtime.atomic import write_text

    cards = {path: upgrade_file(path) for path in args.upgrade}  # all checked, then written
    for path, card in cards.items():
        write_text(path, card_text(card))
        print(f"upgraded: {path} ({card.label}, overall {card.scores.overall:.3f})")
    return 0


def _verify(args: argparse.Namespace) -> int:
    from elastic_gym.benchmark.verify import verify_card

    report = verify_card(
        args.verify,
        suite=args.suite,
        output_dir=args.output,
        workers=args.workers,
        backend=args.backend,
        progress=not args.no_progress,
        overwrite=args.overwrite,
    )
    print(report.text())
    return 0 if (report.exact if args.exact else report.reproduced) else 1
