"""API keys: created once, shown once, stored as SHA-256 hashes; each belongs to one tenant."""

from __future__ import annotations

import hashlib
import secrets

from sqlalchemy import select
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
    row = session.scalar(
        select(ApiKey).where(ApiKey.key_hash == hash_key(key), ApiKey.revoked_at.is_(None))
    )
    return None if row is None else row.tenant_id


def ensure_local_key(session: Session, configured: str | None) -> str | None:
    """Embedded first start: register the configured key, or create one if no key exists.

    Returns a newly created key (to show once), else None.
    """
    if configured:
        create_key(session, LOCAL_TENANT, configured)
        return None
    if session.scalar(select(ApiKey.id).limit(1)) is None:
        return create_key(session, LOCAL_TENANT)
    return None
