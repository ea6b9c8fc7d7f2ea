"""The committed OpenAPI document matches the app; the migrations match the models."""

from __future__ import annotations

import json

from openapi.generate import PATH, render


def test_openapi_has_not_drifted():
    committed = PATH.read_text(encoding="utf-8")
    current = render()
    assert current == committed, (
        "the app's OpenAPI schema differs from openapi/openapi.json: if the change is intended, "
        "run `python -m openapi.generate` and commit the file"
    )


def test_operation_ids_are_stable_and_unique():
    doc = json.loads(PATH.read_text(encoding="utf-8"))
    ops = [o["operationId"] for p in doc["paths"].values() for o in p.values()]
    assert len(ops) == len(set(ops))
    for op in ("create_scan", "create_fit", "get_fit", "get_fit_result", "delete_scan"):
        assert op in ops


def test_request_bodies_say_what_the_server_checks():
    """Fit modes and body sources are unions (oneOf); names the routes check are enums."""
    from core.measure import MEASUREMENTS
    from core.rig import load_rig
    from core.template import load_template

    doc = json.loads(PATH.read_text(encoding="utf-8"))
    schemas = doc["components"]["schemas"]

    def body(path: str) -> dict:
        return doc["paths"][path]["post"]["requestBody"]["content"]["application/json"]["schema"]

    fits = [r["$ref"].rsplit("/", 1)[1] for r in body("/v1/fits")["oneOf"]]
    assert fits == ["FullFit", "MarkerlessFit", "MarkersOnlyFit", "MeasurementsFit"]
    assert schemas["FullFit"]["properties"]["scan_id"]["type"] == "string"
    assert "scan_id" in schemas["FullFit"]["required"]
    sources = [r["$ref"].rsplit("/", 1)[1] for r in body("/v1/bodies")["oneOf"]]
    assert sources == ["ModelBody", "FitBody", "MorphBody"]

    def keys(schema: str, prop: str) -> set[str]:
        return set(schemas[schema]["properties"][prop]["propertyNames"]["enum"])

    assert keys("BodyPose", "rotations") == set(load_rig().names)
    assert keys("FullFit", "markers") == set(load_template().landmarks)
    assert keys("MeasurementsFit", "measurements") == set(MEASUREMENTS)
    assert (
        {"height_m", "weight_kg", "age"} <= keys("BodyEdit", "delta") == keys("BodyEdit", "target")
    )


def test_migrations_match_models(tmp_path):
    from alembic.autogenerate import compare_metadata
    from alembic.migration import MigrationContext

    from service.db import get_engine, migrate
    from service.models import Base
    from service.settings import Settings

    settings = Settings(data_dir=tmp_path, database_url=None)
    migrate(settings)
    with get_engine(settings).connect() as conn:
        diff = compare_metadata(MigrationContext.configure(conn), Base.metadata)
    assert diff == [], f"models and migrations differ (add an Alembic revision): {diff}"
