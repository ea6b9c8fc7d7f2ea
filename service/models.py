"""SQLAlchemy 2 models: tenants, API keys (hashed), scans, fits (jobs), bodies and blobs.

The ``fits`` row is the source of truth of a job: it is committed before the job is enqueued and
every state change is a transaction on it. Schema changes go through Alembic
(``service/migrations``); a test fails when these models and the migrations disagree.
"""

from __future__ import annotations

import secrets
from datetime import UTC, datetime
from typing import Any, ClassVar

from sqlalchemy import (
    JSON,
    BigInteger,
    DateTime,
    ForeignKey,
    Index,
    Integer,
    LargeBinary,
    String,
    Text,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column, relationship

FIT_STATES = ("queued", "running", "succeeded", "failed")
FIT_MODES = ("full", "markerless", "markers_only", "measurements")


def utcnow() -> datetime:
    """Timezone-aware now (UTC)."""
    return datetime.now(UTC)


def new_id(prefix: str) -> str:
    """An opaque id such as ``scn_3f0c…`` (prefix + 20 hex digits)."""
    return f"{prefix}_{secrets.token_hex(10)}"


class Base(DeclarativeBase):
    type_annotation_map: ClassVar[dict[Any, Any]] = {
        datetime: DateTime(timezone=True),
        dict[str, Any]: JSON,
    }


class Tenant(Base):
    __tablename__ = "tenants"

    id: Mapped[str] = mapped_column(String(32), primary_key=True)
    name: Mapped[str] = mapped_column(String(200), unique=True)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class ApiKey(Base):
    __tablename__ = "api_keys"

    id: Mapped[str] = mapped_column(String(32), primary_key=True)
    tenant_id: Mapped[str] = mapped_column(ForeignKey("tenants.id", ondelete="CASCADE"), index=True)
    key_hash: Mapped[str] = mapped_column(String(64), unique=True)  # sha256 hex of the key
    prefix: Mapped[str] = mapped_column(String(16))  # first characters, to recognise a key
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    revoked_at: Mapped[datetime | None] = mapped_column(default=None)

    tenant: Mapped[Tenant] = relationship()


class Scan(Base):
    __tablename__ = "scans"
    __table_args__ = (Index("ix_scans_tenant_created", "tenant_id", "created_at", "id"),)

    id: Mapped[str] = mapped_column(String(32), primary_key=True)
    tenant_id: Mapped[str] = mapped_column(ForeignKey("tenants.id", ondelete="CASCADE"))
    filename: Mapped[str] = mapped_column(String(255))
    format: Mapped[str] = mapped_column(String(8))
    size_bytes: Mapped[int] = mapped_column(BigInteger)
    n_vertices: Mapped[int] = mapped_column(BigInteger)
    n_faces: Mapped[int] = mapped_column(BigInteger)
    units: Mapped[str] = mapped_column(String(8), default="auto")
    up: Mapped[str] = mapped_column(String(8), default="auto")
    markers: Mapped[dict[str, Any] | None] = mapped_column(default=None)  # name -> [x, y, z]
    blob_key: Mapped[str] = mapped_column(String(255))
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class Fit(Base):
    __tablename__ = "fits"
    __table_args__ = (
        Index("ix_fits_tenant_created", "tenant_id", "created_at", "id"),
        Index("ix_fits_state", "state"),
    )

    id: Mapped[str] = mapped_column(String(32), primary_key=True)
    tenant_id: Mapped[str] = mapped_column(ForeignKey("tenants.id", ondelete="CASCADE"))
    # None for a markers-only fit (no scan); such a fit is deleted with ``DELETE /v1/fits/{id}``
    scan_id: Mapped[str | None] = mapped_column(
        ForeignKey("scans.id", ondelete="CASCADE"), index=True, default=None
    )
    mode: Mapped[str] = mapped_column(String(16), default="full", server_default="full")
    state: Mapped[str] = mapped_column(String(16), default="queued")
    options: Mapped[dict[str, Any]] = mapped_column(default=dict)
    markers: Mapped[dict[str, Any] | None] = mapped_column(default=None)  # overrides the scan's
    progress: Mapped[dict[str, Any] | None] = mapped_column(default=None)
    error: Mapped[dict[str, Any] | None] = mapped_column(default=None)
    report: Mapped[dict[str, Any] | None] = mapped_column(default=None)
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    task_id: Mapped[str | None] = mapped_column(String(64), default=None)
    worker: Mapped[str | None] = mapped_column(String(255), default=None)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    enqueued_at: Mapped[datetime | None] = mapped_column(default=None)
    started_at: Mapped[datetime | None] = mapped_column(default=None)
    heartbeat_at: Mapped[datetime | None] = mapped_column(default=None)
    finished_at: Mapped[datetime | None] = mapped_column(default=None)
    fit_seconds: Mapped[float | None] = mapped_column(default=None)


class Body(Base):
    """A stored body (template order, metres): synthesised from a shape model, taken from a
    succeeded fit, or edited from another body. The vertices are a float64 ``.npy`` blob.

    A body made from a fit, and every body edited from it, keeps that fit's id in ``fit_id``
    (derived personal data): the row goes with the fit (``ON DELETE CASCADE``, so with its scan
    too) and its blob lives under the fit's blob prefix (``<tenant>/fits/<fit>/bodies/…``),
    which the fit's and the scan's ``DELETE`` remove.
    """

    __tablename__ = "bodies"
    __table_args__ = (Index("ix_bodies_tenant_created", "tenant_id", "created_at", "id"),)

    id: Mapped[str] = mapped_column(String(32), primary_key=True)
    tenant_id: Mapped[str] = mapped_column(ForeignKey("tenants.id", ondelete="CASCADE"))
    model: Mapped[str] = mapped_column(String(64))
    sex: Mapped[str] = mapped_column(String(16))
    source: Mapped[str] = mapped_column(String(16))  # model | fit | edit
    fit_id: Mapped[str | None] = mapped_column(
        ForeignKey("fits.id", ondelete="CASCADE"), index=True, default=None
    )
    derived_from: Mapped[str | None] = mapped_column(
        ForeignKey("bodies.id", ondelete="SET NULL"), index=True, default=None
    )
    params: Mapped[dict[str, Any]] = mapped_column(default=dict)  # the creating request
    features: Mapped[dict[str, Any]] = mapped_column(default=dict)  # predicted by the model
    blob_key: Mapped[str] = mapped_column(String(255))
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class Blob(Base):
    """Metadata of a stored file (scan upload or fit result); the bytes live in the blob store."""

    __tablename__ = "blobs"

    key: Mapped[str] = mapped_column(String(255), primary_key=True)
    tenant_id: Mapped[str] = mapped_column(ForeignKey("tenants.id", ondelete="CASCADE"))
    scan_id: Mapped[str | None] = mapped_column(
        ForeignKey("scans.id", ondelete="CASCADE"), index=True, default=None
    )
    fit_id: Mapped[str | None] = mapped_column(
        ForeignKey("fits.id", ondelete="CASCADE"), index=True, default=None
    )
    kind: Mapped[str] = mapped_column(String(32))  # scan, result.glb, result.ply, …
    content_type: Mapped[str] = mapped_column(String(100))
    size_bytes: Mapped[int] = mapped_column(BigInteger)
    sha256: Mapped[str] = mapped_column(String(64))
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    note: Mapped[str | None] = mapped_column(Text, default=None)


class BlobData(Base):
    """Blob bytes in the database (``BODYSPACE_BLOB_BACKEND=database``), in chunks of ≤ 4 MB."""

    __tablename__ = "blob_data"

    key: Mapped[str] = mapped_column(String(255), primary_key=True)
    seq: Mapped[int] = mapped_column(Integer, primary_key=True)
    data: Mapped[bytes] = mapped_column(LargeBinary)
