"""Service subcommands of ``bodyspace``: ``serve``, ``keys create --tenant NAME``,
``keys list [--tenant NAME]``, ``keys revoke ID_OR_PREFIX`` (``worker`` is :mod:`worker.cli`'s).

Registered by ``service/cli.py`` through :func:`register`. All read the same settings
(``BODYSPACE_*``, see :mod:`service.settings`).
"""

from __future__ import annotations

import argparse
import signal
import socket
import sys
import threading


def _serve(args: argparse.Namespace) -> int:
    import uvicorn

    if args.workers < 1:
        print("bodyspace: error: --workers must be at least 1", flush=True)
        return 2
    if args.workers > 1 and hasattr(socket, "SO_REUSEPORT"):
        return _serve_processes(args)
    uvicorn.run(
        "service.app:app",
        host=args.host,
        port=args.port,
        log_level=args.log_level,
        proxy_headers=True,
        workers=args.workers if args.workers > 1 else None,
    )
    return 0


#: Exit code of an API process whose start failed (uvicorn's ``STARTUP_FAILURE``).
STARTUP_FAILURE = 3


def _listen_socket(host: str, port: int) -> socket.socket:
    """A TCP socket bound to ``host:port`` with ``SO_REUSEPORT``: each API process has its own
    and the kernel spreads new connections over them (by hash), instead of whichever process
    wakes first taking them from one shared socket (32 connections split 25/7 seen)."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
    try:
        sock.bind((host, port))
    except OSError:
        sock.close()
        raise
    sock.set_inheritable(False)
    return sock


def _serve_one(host: str, port: int, log_level: str, parent_pid: int) -> None:
    """One API process of ``serve --workers N`` (a spawned child): its own listening socket;
    stops (SIGTERM: a graceful shutdown) when the supervising process dies."""
    import uvicorn

    from service.runtime import die_with_parent

    die_with_parent(parent_pid, signal.SIGTERM)  # started from the main thread: pdeathsig holds

    config = uvicorn.Config(
        "service.app:app", host=host, port=port, log_level=log_level, proxy_headers=True
    )
    server = uvicorn.Server(config)
    server.run(sockets=[_listen_socket(host, port)])
    if not server.started:
        sys.exit(STARTUP_FAILURE)


def _serve_processes(args: argparse.Namespace) -> int:
    """``serve --workers N``: N API processes, each listening on the port with ``SO_REUSEPORT``;
    one that dies is started again; SIGTERM/SIGINT stop them all. In embedded mode they share
    the data folder (SQLite in WAL mode, the blob folder) and one of them runs the fits
    (:class:`service.jobs.EmbeddedRunner`)."""
    import multiprocessing
    import os

    try:  # fail now, with a message, if the port is taken by a socket without SO_REUSEPORT
        _listen_socket(args.host, args.port).close()
    except OSError as e:
        print(f"bodyspace: error: cannot listen on {args.host}:{args.port}: {e}", flush=True)
        return 2
    ctx = multiprocessing.get_context("spawn")
    stop = threading.Event()

    def new() -> multiprocessing.process.BaseProcess:
        p = ctx.Process(
            target=_serve_one,
            args=(args.host, args.port, args.log_level, os.getpid()),
            name="bodyspace-api",
        )
        p.start()
        return p

    def on_signal(signum: int, _frame: object) -> None:
        stop.set()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGTERM, signal.SIGINT)}
    procs = [new() for _ in range(args.workers)]
    print(
        f"bodyspace: {args.workers} API processes on http://{args.host}:{args.port} "
        f"(pids {', '.join(str(p.pid) for p in procs)})",
        flush=True,
    )
    code = 0
    try:
        while not stop.wait(0.5):
            for i, p in enumerate(procs):
                if p.is_alive():
                    continue
                if p.exitcode == STARTUP_FAILURE:
                    print(f"bodyspace: error: API process {p.pid} failed to start", flush=True)
                    stop.set()
                    code = 1
                    break
                print(
                    f"bodyspace: API process {p.pid} exited ({p.exitcode}): restarting it",
                    flush=True,
                )
                procs[i] = new()
    finally:
        for p in procs:
            if p.is_alive():
                p.terminate()
        for p in procs:
            p.join(timeout=30)
            if p.is_alive():
                p.kill()
                p.join()
        for s, h in old.items():
            signal.signal(s, h)
    return code


def _keys_create(args: argparse.Namespace) -> int:
    from service.auth import create_key
    from service.db import migrate, session_scope

    migrate()
    with session_scope() as s:
        key = create_key(s, args.tenant)
    print(f"API key for tenant {args.tenant!r} (shown once): {key}")
    return 0


def _keys_list(args: argparse.Namespace) -> int:
    from sqlalchemy import select

    from service.db import migrate, session_scope
    from service.models import ApiKey, Tenant

    migrate()
    with session_scope() as s:
        q = select(ApiKey, Tenant.name).join(Tenant, Tenant.id == ApiKey.tenant_id)
        if args.tenant:
            q = q.where(Tenant.name == args.tenant)
        rows = s.execute(q.order_by(Tenant.name, ApiKey.created_at)).all()
        print(f"{'ID':<26} {'TENANT':<20} {'PREFIX':<14} {'CREATED':<20} REVOKED")
        for key, tenant in rows:
            revoked = key.revoked_at.strftime("%Y-%m-%d %H:%M:%S") if key.revoked_at else "-"
            created = key.created_at.strftime("%Y-%m-%d %H:%M:%S")
            print(f"{key.id:<26} {tenant:<20} {key.prefix:<14} {created:<20} {revoked}")
    return 0


def _keys_revoke(args: argparse.Namespace) -> int:
    from sqlalchemy import or_, select

    from service.db import migrate, session_scope
    from service.models import ApiKey, utcnow
    from service.settings import get_settings

    migrate()
    with session_scope() as s:
        keys = list(
            s.scalars(select(ApiKey).where(or_(ApiKey.id == args.key, ApiKey.prefix == args.key)))
        )
        if len(keys) != 1:
            what = "no key" if not keys else f"{len(keys)} keys"
            print(f"bodyspace: error: {what} with id or prefix {args.key!r} (see keys list)")
            return 2
        if keys[0].revoked_at is None:
            keys[0].revoked_at = utcnow()
    ttl = get_settings().api_key_cache_ttl_s
    print(f"revoked {keys[0].id} ({keys[0].prefix}…); API processes refuse it within {ttl:g} s")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``serve`` and ``keys`` to the ``bodyspace`` command line."""
    p = subparsers.add_parser("serve", help="run the HTTP API (uvicorn)")
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=8000)
    p.add_argument("--log-level", default="info")
    p.add_argument(
        "--workers",
        type=int,
        default=1,
        help="API processes, each listening on the port (SO_REUSEPORT); in embedded mode they "
        "share the data folder and one of them runs the fits (default 1)",
    )
    p.set_defaults(func=_serve)

    p = subparsers.add_parser("keys", help="manage API keys")
    ks = p.add_subparsers(dest="keys_command", metavar="ACTION", required=True)
    c = ks.add_parser("create", help="create a key for a tenant and print it")
    c.add_argument("--tenant", required=True, help="tenant name (created if new)")
    c.set_defaults(func=_keys_create)
    c = ks.add_parser("list", help="list keys (id, tenant, prefix, created, revoked; no secret)")
    c.add_argument("--tenant", default=None, help="only this tenant's keys")
    c.set_defaults(func=_keys_list)
    c = ks.add_parser(
        "revoke",
        help="revoke a key (by id or prefix); refused within BODYSPACE_API_KEY_CACHE_TTL_S",
    )
    c.add_argument("key", help="the key's id (key_…) or prefix (first 12 characters)")
    c.set_defaults(func=_keys_revoke)


def main(argv: list[str] | None = None) -> int:
    """``python -m service.commands …`` (the same commands without the rest of the CLI)."""
    parser = argparse.ArgumentParser(prog="bodyspace")
    register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return int(args.func(args) or 0)


if __name__ == "__main__":
    raise SystemExit(main())
