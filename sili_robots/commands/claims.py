"""``sili claims DIR``: the paper's claims decided from a results collection of the grid."""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

from sili_robots.atomic import write_text
from sili_robots.commands.common import path_arg
from sili_robots.errors import ConfigError

#: the README block ``--write`` replaces
START, END = "<!-- claims:start -->", "<!-- claims:end -->"


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "claims",
        help="the paper's claims, decided from the grid's results (a markdown table)",
        description="Decides each claim of the paper (rules in sili_robots/claims.py) from the "
        "grid's runs in DIR (`sili grid` / `sili collect`), those finished at the grid's budget "
        "(paper_grid.py), and prints a markdown table.",
    )
    p.add_argument("directory", type=path_arg, metavar="DIR")
    p.add_argument(
        "--write",
        type=path_arg,
        metavar="FILE",
        help=f"also replace the table between {START} and {END} in FILE (e.g. README.md)",
    )
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from sili_robots.claims import BELOW_BUDGET, claims_table, markdown, other_dynamics
    from sili_robots.plot_data import load_results

    if args.write is not None:
        _claims_block(args.write)  # a wrong file is named before the results are read
    df = load_results(args.directory)
    claims = claims_table(df)
    left_out = other_dynamics(df)
    if left_out:
        print(
            f"sili claims: left out {len(left_out)} runs with other task arguments than the "
            f"grid's ({', '.join(left_out[:3])}{', ...' if len(left_out) > 3 else ''})",
            file=sys.stderr,
        )
    table = markdown(claims)
    if args.write is not None and all(c.verdict.startswith("not measured") for c in claims):
        raise ConfigError(  # before the table: a failed command prints none
            f"{args.directory} measures none of the claims, so --write {args.write} would "
            "replace its table with 'not measured yet' everywhere; give the grid's results "
            "(results/paper-grid)"
        )
    if args.write is not None:
        _check_keeps_measured(args.write, claims, args.directory)
    elif all(c.verdict.startswith(BELOW_BUDGET) for c in claims):
        print(
            f"sili claims: note: {args.directory} measures none of the claims: each judges only "
            "runs finished at the grid's budget (`sili grid --dry-run` lists its runs)",
            file=sys.stderr,
        )
    print(table, end="")
    if args.write is not None:
        write_block(args.write, table)
    return 0


def _measured_rows(path: Path) -> set[tuple[str, str]]:
    """(claim, task) of the rows the claims block of ``path`` shows decided (a bold verdict)."""
    text, pattern = _claims_block(path)
    rows = set()
    for line in pattern.search(text).group(0).splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 4 and cells[3].startswith("**"):
            rows.add((cells[0], cells[1]))
    return rows


def _check_keeps_measured(path: Path, claims: list, directory: Path) -> None:
    """ConfigError when ``--write`` would replace a decided row of ``path`` with "not measured
    yet" (results of part of the grid, or another folder than the grid's)."""
    measured = _measured_rows(path)
    lost = [
        f"{c.claim} on {c.task}: {c.verdict}"
        for c in claims
        if c.verdict.startswith("not measured") and (c.claim, c.task) in measured
    ]
    if lost:
        more = f"; and {len(lost) - 2} more" if len(lost) > 2 else ""
        raise ConfigError(
            f"--write {path} would replace rows it shows decided with 'not measured yet' "
            f"({'; '.join(lost[:2])}{more}): {directory} lacks what they need; give the grid's "
            "whole results (results/paper-grid), or what the rows name"
        )


def _claims_block(path: Path) -> tuple[str, re.Pattern[str]]:
    """The text of ``path`` and the pattern of its claims block, or ConfigError saying why not."""
    if path.is_dir():
        raise ConfigError(f"--write {path} is a directory; give the file with the claims block")
    if not path.is_file():
        raise ConfigError(f"--write {path}: no such file")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise ConfigError(
            f"--write {path} is not a text file; give the file with the claims block"
        ) from None
    pattern = re.compile(re.escape(START) + ".*?" + re.escape(END), re.S)
    if not pattern.search(text):
        raise ConfigError(f"--write {path}: it has no {START} ... {END} block to replace")
    return text, pattern


def write_block(path: Path, table: str) -> None:
    """Replace the text between the claims markers of ``path`` with ``table``."""
    text, pattern = _claims_block(path)
    write_text(
        path, pattern.sub(lambda _: f"{START}\n{table}{END}", text, count=1), encoding="utf-8"
    )
