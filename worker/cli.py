"""``bodyspace worker``: registered by ``service/cli.py`` (``PLUGIN_MODULES``), so that
``service`` never imports ``worker`` (the dependency goes one way: worker -> service)."""

from __future__ import annotations

import argparse


def _worker(args: argparse.Namespace) -> int:
    from service.settings import get_settings

    if not get_settings().broker_url:
        print(
            "bodyspace: error: `bodyspace worker` needs BODYSPACE_BROKER_URL (e.g. "
            "redis://127.0.0.1:6379/0); without a broker `bodyspace serve` runs fits itself",
            flush=True,
        )
        return 2
    from worker.tasks import main

    main(concurrency=args.concurrency, loglevel=args.log_level.upper(), hostname=args.hostname)
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``worker`` to the ``bodyspace`` command line."""
    p = subparsers.add_parser("worker", help="run a Celery worker (distributed mode)")
    p.add_argument("--concurrency", type=int, default=None, help="pool processes (default: CPUs)")
    p.add_argument("--hostname", default=None, help="Celery node name (default: celery@HOST)")
    p.add_argument("--log-level", default="info")
    p.set_defaults(func=_worker)


def main(argv: list[str] | None = None) -> int:
    """``python -m worker.cli worker …``."""
    parser = argparse.ArgumentParser(prog="bodyspace")
    register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return int(args.func(args) or 0)


if __name__ == "__main__":
    raise SystemExit(main())
