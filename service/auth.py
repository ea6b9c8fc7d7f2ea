"""API keys: created once, shown once, stored as SHA-256 hashes; each belongs to one tenant.

Requests look keys up through a :class:`KeyCache` (one per API process): a key's tenant, or the
fact that it is invalid, is remembered for ``BODYSPACE_API_KEY_CACHE_TTL_S`` seconds (default
30) after the database lookup. So a key revoked or deleted in the database keeps working for at
most that long in each API process that used it; a key created after being tried (only possible
for a key chosen by hand) is accepted at most that long later. ``0`` turns the cache off.
"""

from __future__ import annotations

import hashlib
import secrets
import threading
import time
from collections import OrderedDict
from collections.abc import Callable

from sqlalchemy import select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from service.models import ApiKey, Tenant, new_id

KEY_PREFIX = "bsk_"
LOCAL_TENANT = "local"


def hash_key(key: str) -> str:
    """SHA-256 hex of a key (keys are 256-bit random, so a fast hash is enough)."""
    return hashlib.sha256(key.encode("utf-8")).hexdigest()


def get_or_create_tenant(session: Session, name: str) -> Tenant:
    tenant = session.scalar(select(Tenant).where(Tenant.name == name))
    if tenant is None:
        tenant = Tenant(id=new_id("ten"), name=name)
        session.add(tenant)
        session.flush()
    return tenant


def create_key(session: Session, tenant_name: str, key: str | None = None) -> str:
    """Create (or register a given) key for ``tenant_name``; returns the plain key."""
    tenant = get_or_create_tenant(session, tenant_name)
    key = key or KEY_PREFIX + secrets.token_urlsafe(32)
    h = hash_key(key)
    if session.scalar(select(ApiKey).where(ApiKey.key_hash == h)) is None:
        session.add(ApiKey(id=new_id("key"), tenant_id=tenant.id, key_hash=h, prefix=key[:12]))
        session.flush()
    return key


def tenant_for_key(session: Session, key: str) -> str | None:
    """The tenant id of a valid, unrevoked key, else None."""
    return tenant_for_hash(session, hash_key(key))


def tenant_for_hash(session: Session, key_hash: str) -> str | None:
    """The tenant id of the valid, unrevoked key with SHA-256 hex ``key_hash``, else None."""
    return session.scalar(
        select(ApiKey.tenant_id).where(ApiKey.key_hash == key_hash, ApiKey.revoked_at.is_(None))
    )


_MISS = object()


class KeyCache:
    """In-process cache of key hash -> tenant id (or None for an invalid key), with a TTL.

    Two bounded LRUs: valid keys (``maxsize``) and invalid ones (``max_invalid``), so that a
    flood of made-up keys can neither grow memory nor evict the valid keys. Entries expire
    ``ttl_s`` after their database lookup (using a key does not extend it): a revoked or deleted
    key stops working at most ``ttl_s`` later. ``ttl_s <= 0`` disables caching. Thread-safe.

    Parameters
    ----------
    ttl_s : seconds an answer is reused.
    maxsize : valid keys kept (least recently used dropped first).
    max_invalid : invalid keys kept.
    clock : monotonic clock (tests pass a fake one).
    """

    def __init__(
        self,
        ttl_s: float,
        maxsize: int = 10_000,
        max_invalid: int = 1_024,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.ttl_s = float(ttl_s)
        self._max = {True: max(0, int(maxsize)), False: max(0, int(max_invalid))}
        self._lru: dict[bool, OrderedDict[str, tuple[float, str | None]]] = {
            True: OrderedDict(),
            False: OrderedDict(),
        }
        self._clock = clock
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self._lru[True]) + len(self._lru[False])

    def get(self, key_hash: str) -> object:
        """The cached tenant id (``str``), ``None`` for a known invalid key, or
        :attr:`KeyCache.MISS` when the database must be asked."""
        if self.ttl_s <= 0:
            return _MISS
        now = self._clock()
        with self._lock:
            for valid in (True, False):
                lru = self._lru[valid]
                hit = lru.get(key_hash)
                if hit is None:
                    continue
                if hit[0] <= now:
                    del lru[key_hash]
                    return _MISS
                lru.move_to_end(key_hash)
                return hit[1]
        return _MISS

    def put(self, key_hash: str, tenant: str | None) -> None:
        """Remember the database's answer for ``key_hash`` (``None``: invalid) for ``ttl_s``."""
        if self.ttl_s <= 0:
            return
        valid = tenant is not None
        lru, cap = self._lru[valid], self._max[valid]
        with self._lock:
            self._lru[not valid].pop(key_hash, None)
            lru[key_hash] = (self._clock() + self.ttl_s, tenant)
            lru.move_to_end(key_hash)
            while len(lru) > cap:
                lru.popitem(last=False)

    def clear(self) -> None:
        with self._lock:
            for lru in self._lru.values():
                lru.clear()

    MISS = _MISS


def ensure_local_key(session: Session, configured: str | None) -> str | None:
    """Embedded first start: register the configured key, or create one if no key exists.

    Returns a newly created key (to show once), else None.
    """
    if configured:
        if session.get_bind().dialect.name == "sqlite":  # API processes start one at a time
            create_key(session, LOCAL_TENANT, configured)
            return None
        try:  # `serve --workers N`: the processes start at once and may race to register it
            with session.begin_nested():
                create_key(session, LOCAL_TENANT, configured)
        except IntegrityError:
            pass  # another API process registered it
        return None
    if session.scalar(select(ApiKey.id).limit(1)) is None:
        return create_key(session, LOCAL_TENANT)
    return None
