"""`netapp serve --candidate` and how the candidate is judged: the flags, and the settings they fill (docs/rollouts.md).
Argparse and plain values only: `netapp serve` parses them before anything loads."""

from __future__ import annotations

import argparse

from netapp.server.settings import Policy, Settings, Shadowing


def add_rollout_arguments(parser: argparse.ArgumentParser) -> None:
    """--candidate and how it is judged (docs/rollouts.md)."""
    policy, shadowing = Policy(), Shadowing()
    group = parser.add_argument_group("rollout (docs/rollouts.md)")
    group.add_argument(
        "--candidate",
        metavar="MODEL",
        help="a candidate model (path or http(s) URL, optionally #sha256=HEX) run beside --model on a sample of frames "
        "and promoted in place when it agrees, else rolled back; GET /rollout shows how it goes",
    )
    group.add_argument(
        "--shadow-sample", type=float, default=shadowing.sample, help="share of frames it sees (%(default)s)"
    )
    group.add_argument(
        "--shadow-budget",
        type=float,
        default=shadowing.budget,
        help="its time at most this share of the current model's; past it sampled frames are skipped (%(default)s)",
    )
    group.add_argument(
        "--promote-after", type=int, default=policy.promote_after, help="frames compared before promotion (%(default)s)"
    )
    group.add_argument(
        "--min-agreement",
        type=float,
        default=policy.min_agreement,
        help="agreement (F1 of matched boxes, top-1 for a classifier) below this over the window rolls back "
        "(%(default)s)",
    )
    group.add_argument(
        "--max-slowdown",
        type=float,
        default=policy.max_slowdown,
        help="a candidate slower than this many times the current model at p95 rolls back (%(default)s)",
    )
    group.add_argument(
        "--canary-share",
        type=float,
        default=policy.canary_share,
        help="after the shadow agrees, this share of robots (by session, stable) get its results for --promote-after "
        "more compared frames before the full switch (%(default)s: no canary)",
    )


def rollout_settings(args: argparse.Namespace, settings: Settings) -> None:
    """Fill the rollout's settings from the flags; ValueError, one line, for values it cannot use."""
    policy = Policy(
        promote_after=args.promote_after,
        min_agreement=args.min_agreement,
        max_slowdown=args.max_slowdown,
        canary_share=args.canary_share,
    )
    shadowing = Shadowing(sample=args.shadow_sample, budget=args.shadow_budget)
    problem = policy.problem() or shadowing.problem()
    if problem:
        raise ValueError(f"--candidate: {problem}")
    if args.candidate and args.processor and ":" in args.processor:
        raise ValueError("--candidate is for the built-in model processors: a module:Class loads its own weights")
    settings.candidate = args.candidate
    settings.rollout_policy = policy
    settings.shadowing = shadowing
