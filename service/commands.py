"""Service subcommands of ``bodyspace``: ``serve``, ``worker``, ``keys create --tenant NAME``.

Registered by ``service/cli.py`` through :func:`register`. All read the same settings
(``BODYSPACE_*``, see :mod:`service.settings`).
"""

from __future__ import annotations

import argparse


def _serve(args: argparse.Namespace) -> int:
    import uvicorn

    from service.settings import get_settings

    if args.workers < 1:
        print("bodyspace: error: --workers must be at least 1", flush=True)
        return 2
    if args.workers > 1 and not get_settings().distributed:
        print(
            "bodyspace: error: --workers > 1 needs distributed mode (BODYSPACE_DATABASE_URL and "
            "BODYSPACE_BROKER_URL): in embedded mode one API process owns the data folder and "
            "runs its fits",
            flush=True,
        )
        return 2
    uvicorn.run(
        "service.app:app",
        host=args.host,
        port=args.port,
        log_level=args.log_level,
        proxy_headers=True,
        workers=args.workers if args.workers > 1 else None,
    )
    return 0


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


def _keys_create(args: argparse.Namespace) -> int:
    from service.auth import create_key
    from service.db import migrate, session_scope

    migrate()
    with session_scope() as s:
        key = create_key(s, args.tenant)
    print(f"API key for tenant {args.tenant!r} (shown once): {key}")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``serve``, ``worker`` and ``keys`` to the ``bodyspace`` command line."""
    p = subparsers.add_parser("serve", help="run the HTTP API (uvicorn)")
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=8000)
    p.add_argument("--log-level", default="info")
    p.add_argument(
        "--workers",
        type=int,
        default=1,
        help="API processes sharing the port (distributed mode only; default 1)",
    )
    p.set_defaults(func=_serve)

    p = subparsers.add_parser("worker", help="run a Celery worker (distributed mode)")
    p.add_argument("--concurrency", type=int, default=None, help="pool processes (default: CPUs)")
    p.add_argument("--hostname", default=None, help="Celery node name (default: celery@HOST)")
    p.add_argument("--log-level", default="info")
    p.set_defaults(func=_worker)

    p = subparsers.add_parser("keys", help="manage API keys")
    ks = p.add_subparsers(dest="keys_command", metavar="ACTION", required=True)
    c = ks.add_parser("create", help="create a key for a tenant and print it")
    c.add_argument("--tenant", required=True, help="tenant name (created if new)")
    c.set_defaults(func=_keys_create)


def main(argv: list[str] | None = None) -> int:
    """``python -m service.commands …`` (the same commands without the rest of the CLI)."""
    parser = argparse.ArgumentParser(prog="bodyspace")
    register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return int(args.func(args) or 0)


if __name__ == "__main__":
    raise SystemExit(main())
