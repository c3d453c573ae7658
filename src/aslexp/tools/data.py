"""`aslexp data fetch|check --root DIR`: get the public data, or verify a data root."""

from __future__ import annotations

import argparse
import logging
import sys

from aslexp.data.root import resolve_data_root


def data_main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="aslexp data", description=__doc__)
    sub = parser.add_subparsers(dest="action", required=True)
    fetch = sub.add_parser("fetch", help="download the public files listed in the data README")
    fetch.add_argument("--root", required=True, help="data folder to fill")
    fetch.add_argument("--timeout", type=float, default=20.0, help="seconds per request")
    check = sub.add_parser("check", help="verify a data root against its SHA256SUMS")
    check.add_argument("--root", default=None, help="data root (default: data.root setting)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")

    from aslexp.data import fetch as fetch_module

    if args.action == "fetch":
        try:
            report = fetch_module.fetch_data(args.root, timeout=args.timeout)
        except fetch_module.FetchError as err:
            print(f"aslexp data fetch: {err}", file=sys.stderr)
            return 1
        print(report.summary() if hasattr(report, "summary") else report)
        return 0
    root = resolve_data_root(args.root)
    report = fetch_module.check_data(root)
    print(report.summary())
    return 0 if report.all_ok else 1
