"""What a case file says it is: its identity, recorded inside it, and the check that it belongs to a store.

Every case file carries, in its Parquet key-value metadata under :data:`IDENTITY_KEY`, one JSON object::

    {"config_hash": "<sha256 of the campaign configuration>", "case_id": 1000002, "campaign_seed": 7,
     "estimators": ["dimes", "yes_man"], "result_schema_version": 1}

written by the worker that computed the case (:func:`campaign.store.case_files.write_case_rows`). A store
counts a case file only when that record matches the place the file is found (:class:`StoreIdentity`,
read from the store's ``manifest.json``): the store's configuration hash and seed, the store's estimator
list (names, in ``[[estimators]]`` order), the case id of the file's name and the
:data:`~campaign.store.result_schema.RESULT_SCHEMA_VERSION` of this code; and when the file's rows
agree with it (one row per estimator, in that order, each with that case id and seed). A file that
fails is *foreign*: another campaign's (another seed, another configuration), another code's (another
schema version), or written before identities were recorded (no record at all). It is never counted or
read; ``campaign submit`` moves it to ``rejected/`` and computes the case again.

``pyarrow.parquet.read_schema(path).metadata[b"moc2dimes.case_identity"]`` shows the record of a file.
"""
from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import pyarrow as pa

from campaign.store.result_schema import RESULT_SCHEMA_VERSION

IDENTITY_KEY = b"moc2dimes.case_identity"
IDENTITY_FIELDS = ("config_hash", "case_id", "campaign_seed", "estimators", "result_schema_version")
FOREIGN = "foreign"
"""First word of every identity problem (``campaign verify`` and ``rejected.log`` lines)."""


@dataclass(frozen=True)
class StoreIdentity:
    """What every counted case file of a store records.

    Attributes
    ----------
    config_hash : str
        The campaign's configuration hash (``manifest.json`` ``config_hash``).
    campaign_seed : int
        The campaign's seed (``manifest.json`` ``seed``).
    estimators : tuple of str or None
        Estimator names in ``[[estimators]]`` order (``manifest.json`` ``estimators``; None: a manifest
        written before it was recorded, the names are then not compared).
    result_schema_version : int
        :data:`~campaign.store.result_schema.RESULT_SCHEMA_VERSION` of the code that wrote the file.
    """

    config_hash: str
    campaign_seed: int
    estimators: tuple[str, ...] | None
    result_schema_version: int = RESULT_SCHEMA_VERSION

    @classmethod
    def of_manifest(cls, manifest: Mapping[str, Any]) -> StoreIdentity:
        """The identity a store's verified manifest declares (the schema version is this code's)."""
        names = manifest.get("estimators")
        return cls(config_hash=str(manifest["config_hash"]), campaign_seed=int(manifest["seed"]),
                   estimators=tuple(str(name) for name in names) if isinstance(names, list) else None)

    def record(self, case_id: int) -> dict:
        """The JSON record of case ``case_id`` (what :func:`identity_metadata` stores)."""
        return {"config_hash": self.config_hash, "case_id": int(case_id), "campaign_seed": int(self.campaign_seed),
                "estimators": list(self.estimators or ()), "result_schema_version": int(self.result_schema_version)}


def identity_metadata(identity: StoreIdentity, case_id: int) -> dict[bytes, bytes]:
    """The Parquet key-value metadata recording a case file's identity."""
    return {IDENTITY_KEY: json.dumps(identity.record(case_id), sort_keys=True).encode()}


BATCH_IDENTITY_KEY = b"moc2dimes.batch_identity"
BATCH_FIELDS = ("config_hash", "campaign_seed", "estimators", "result_schema_version", "case_ids", "states",
                "written_ns")


def batch_metadata(identity: StoreIdentity, case_ids: Sequence[int], states: Sequence[str],
                   written_ns: int) -> dict[bytes, bytes]:
    """The Parquet key-value metadata of a batch file: the campaign's record (as :meth:`StoreIdentity.record`
    without the case id) with the batch's ``case_ids`` in row order, their ``states`` ('ok', or 'failed':
    the simulation failed) and ``written_ns`` (the writer's clock: of two batches holding a case, the
    later one counts)."""
    record = {key: value for key, value in identity.record(0).items() if key != "case_id"}
    record |= {"case_ids": [int(case_id) for case_id in case_ids], "states": list(states),
               "written_ns": int(written_ns)}
    return {BATCH_IDENTITY_KEY: json.dumps(record, sort_keys=True).encode()}


def read_batch_identity(metadata: Mapping[bytes, bytes] | None) -> tuple[dict | None, str | None]:
    """A batch file's record from its key-value metadata: (record, None) or (None, what is wrong)."""
    record, problem = _json_record(metadata, BATCH_IDENTITY_KEY, BATCH_FIELDS, "batch identity",
                                   "written by hand or by another program")
    if record is None:
        return None, problem
    case_ids, states = record["case_ids"], record["states"]
    if (not isinstance(case_ids, list) or not isinstance(states, list) or not case_ids
            or len(case_ids) != len(states) or not all(isinstance(c, int) for c in case_ids)
            or any(state not in ("ok", "failed") for state in states) or len(set(case_ids)) != len(case_ids)):
        return None, f"{FOREIGN}: its batch identity record has no valid case list"
    return record, None


def campaign_problem(record: Mapping[str, Any], expected: StoreIdentity | None,
                     also: Mapping[str, Any] | None = None) -> str | None:
    """Why a batch's record is not of campaign ``expected`` (every field that differs, one line), or None
    (``expected`` None: only the schema version is compared); ``also``: more fields the record must have
    (a one-case file's ``case_id``), compared first."""
    wanted: dict[str, Any] = {**(also or {}), "result_schema_version": RESULT_SCHEMA_VERSION}
    if expected is not None:
        wanted |= {"config_hash": expected.config_hash, "campaign_seed": int(expected.campaign_seed)}
        if expected.estimators is not None:
            wanted["estimators"] = list(expected.estimators)
    differences = [f"{name} {_shown(record.get(name))} (this store: {_shown(value)})"
                   for name, value in wanted.items() if record.get(name) != value]
    if differences:
        return f"{FOREIGN}: records {'; '.join(differences)}"
    return None


def batch_rows_problem(rows: pa.Table, record: Mapping[str, Any]) -> str | None:
    """Why a batch's rows (columns case_id, campaign_seed, estimator at least) disagree with its record
    (for each recorded case in order, one row per recorded estimator in order, with that case id and the
    recorded seed), or None."""
    import numpy as np

    estimators, case_ids = list(record["estimators"]), record["case_ids"]
    if rows.num_rows != len(estimators) * len(case_ids):
        return (f"{FOREIGN}: {rows.num_rows} rows, its identity record says {len(case_ids)} cases of "
                f"{len(estimators)} estimators")
    if rows.num_rows == 0:
        return f"{FOREIGN}: no rows"
    if rows.column("estimator").to_pylist() != estimators * len(case_ids):
        return f"{FOREIGN}: its rows are not of estimators {estimators} for each case, in order"
    found = rows.column("case_id").to_numpy(zero_copy_only=False)
    if rows.column("case_id").null_count or not np.array_equal(found, np.repeat(case_ids, len(estimators))):
        return f"{FOREIGN}: its rows' case ids are not the {len(case_ids)} cases its identity record lists"
    seeds = rows.column("campaign_seed")
    if seeds.null_count or set(seeds.to_numpy(zero_copy_only=False).tolist()) != {record["campaign_seed"]}:
        return f"{FOREIGN}: its rows' campaign_seed differs from its identity record's {record['campaign_seed']}"
    return None


def read_identity(metadata: Mapping[bytes, bytes] | None) -> tuple[dict | None, str | None]:
    """A file's identity record from its key-value metadata: (record, None) or (None, what is wrong)."""
    return _json_record(metadata, IDENTITY_KEY, IDENTITY_FIELDS, "identity",
                        "written before identities were recorded, by hand or by another program")


def _json_record(metadata: Mapping[bytes, bytes] | None, key: bytes, fields, name: str,
                 absent: str) -> tuple[dict | None, str | None]:
    """The JSON record under ``key`` of a file's key-value metadata, with every one of ``fields``:
    (record, None) or (None, what is wrong; ``name`` names the record, ``absent`` says how a file without one
    came to be)."""
    raw = (metadata or {}).get(key)
    if raw is None:
        return None, (f"{FOREIGN}: no identity record in its Parquet metadata ({absent}), so it cannot be "
                      "attributed to this campaign")
    try:
        record = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, ValueError):
        return None, f"{FOREIGN}: its {name} record is not valid JSON"
    if not isinstance(record, dict) or any(field not in record for field in fields):
        missing = [field for field in fields if not isinstance(record, dict) or field not in record]
        return None, f"{FOREIGN}: its {name} record lacks {', '.join(missing)}"
    return record, None


def _shown(value: Any) -> str:
    if isinstance(value, str) and len(value) == 64:
        return value[:12]                      # a sha256: its first 12 digits are enough to tell
    return json.dumps(value)


def identity_problem(record: Mapping[str, Any], case_id: int, expected: StoreIdentity | None) -> str | None:
    """Why a file's identity record does not belong at its place (every field that differs, in one line),
    or None. ``case_id``: the id in the file's name; ``expected``: the store's identity (None: no
    verified manifest, only the case id and the schema version are compared)."""
    return campaign_problem(record, expected, also={"case_id": int(case_id)})


def rows_problem(rows: pa.Table, record: Mapping[str, Any]) -> str | None:
    """Why a file's rows (columns case_id, campaign_seed, estimator at least) disagree with its identity
    record (one row per recorded estimator, in order, each with the recorded case id and seed), or None."""
    estimators = rows.column("estimator").to_pylist()
    if estimators != list(record["estimators"]):
        return f"{FOREIGN}: its rows are of estimators {estimators}, its identity record says {record['estimators']}"
    for name in ("case_id", "campaign_seed"):
        values = set(rows.column(name).to_pylist())
        if values != {record[name]}:
            return f"{FOREIGN}: its rows have {name} {sorted(values, key=str)}, its identity record says {record[name]}"
    return None


def check_rows_match(rows: Sequence[Mapping[str, Any]], identity: StoreIdentity, case_id: int) -> str | None:
    """Before writing: why ``rows`` (mappings of column to value) are not case ``case_id`` of ``identity``."""
    table = pa.table({name: [row.get(name) for row in rows] for name in ("case_id", "campaign_seed", "estimator")})
    return rows_problem(table, identity.record(case_id))
