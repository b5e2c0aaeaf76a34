"""What differs between two campaign configurations, in words: the fields of a refused change, old -> new.

A store holds the results of one configuration (its hash, :func:`campaign.configuration.campaign_file.hashed_content`).
A submit of another configuration into it is refused; :func:`describe_change` says why, from the two
manifests (the store's and the submit's), in one line:

* every table field whose value differs, ``field: old -> new``, with what the hash leaves out left out here
  too (``[execution]``, ``output_dir``, case counts, the false-valid threshold, a plug-in's ``path``);
  ``[[estimators]]`` entries are matched by name (an added or removed estimator is named as such);
* an input file whose bytes changed (``site.camera``, the trajectory set, terrain files: their sha256, from
  the manifests' ``hash_inputs``), the project's case code (``code_digest``) and a plug-in's own files;
* when every difference touches only some estimators (their ``[[estimators]]`` entries, the reference
  parameters of ``[estimator]`` for the reference entries that do not override them, a plug-in's code),
  which ones, and why they cannot be run again alone: a store keeps each case's result rows, not its
  rendered images, sensor draws or calibration products, so any change means rendering every case again.

A store written before manifests recorded ``hash_inputs`` whose tables are the same is described as a
change of an input file's bytes or of the code, without saying which.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

# Standard library only: the store imports this module, and `campaign status|verify|table` import the store
# without the configuration's models (tests/test_layers.py).

#: ``[campaign]`` keys the configuration hash leaves out (campaign_file.hashed_content).
HASH_EXCLUDED_CAMPAIGN_KEYS = ("output_dir", "false_valid_mps", "cases", "cases_scale")
#: ``[estimator]`` keys that make the calibration products every estimator gets (the fields of
#: campaign.configuration.estimators.CalibrationConfig); its other keys are the reference estimator's.
CALIBRATION_KEYS = ("flat_field", "flat_field_frames")
#: Changes spelled out in the one line; the others are counted.
SHOWN_CHANGES = 6
#: Longest value shown (longer ones are cut with "...").
VALUE_CHARACTERS = 48
ADDED, REMOVED = "(added)", "(removed)"
#: Tables in the order their changes are listed (as in a campaign file; others after them).
TABLE_ORDER = ("site", "campaign", "sensors", "estimator", "scene")
#: The site's file fields (compared by their bytes' sha256, not by their names).
SITE_FILE_FIELDS = ("camera", "trajectory_set")


@dataclass(frozen=True)
class FieldChange:
    """One difference between two configurations.

    Attributes
    ----------
    field : str
        Dotted field (``estimators[1].parameters.min_response``, ``site.camera``, ``code``).
    old, new : str
        The store's and the submit's value, as text.
    estimators : frozenset of str or None
        The estimators whose results alone it changes; None: every estimator's inputs (rendering, sensors,
        calibration, the cases themselves).
    """

    field: str
    old: str
    new: str
    estimators: frozenset[str] | None = None

    def __str__(self) -> str:
        return f"{self.field}: {self.old} -> {self.new}"


def _text(value: Any) -> str:
    text = "(none)" if value is _ABSENT else json.dumps(value, sort_keys=True, default=str)
    return text if len(text) <= VALUE_CHARACTERS else text[:VALUE_CHARACTERS - 3] + "..."


_ABSENT = object()


def _leaves(value: Any, prefix: str) -> dict[str, Any]:
    """Dotted path -> value of every leaf of nested tables (arrays of tables by index, other arrays whole)."""
    if isinstance(value, dict):
        leaves: dict[str, Any] = {}
        for key, item in value.items():
            leaves.update(_leaves(item, f"{prefix}.{key}" if prefix else str(key)))
        return leaves or {prefix: value}
    if isinstance(value, list) and value and all(isinstance(item, dict) for item in value):
        leaves = {}
        for index, item in enumerate(value):
            leaves.update(_leaves(item, f"{prefix}[{index}]"))
        return leaves
    return {prefix: value}


def _compared_tables(config: dict) -> dict:
    """The resolved tables as the hash sees them, paths of hashed files left out (their bytes are compared)."""
    tables = json.loads(json.dumps({name: value for name, value in config.items()
                                    if name not in ("execution", "estimators", "base")}))
    for key in HASH_EXCLUDED_CAMPAIGN_KEYS:
        tables.get("campaign", {}).pop(key, None)
    site = tables.get("site", {})
    for name in SITE_FILE_FIELDS:
        site.pop(name, None)
    for entry in site.get("classes") or []:
        entry.pop("cases", None)
        for name in ("path", "sidecar"):
            (entry.get("terrain") or {}).pop(name, None)
    return tables


def estimator_entries(config: dict, names: list | None = None) -> dict[str, dict]:
    """Estimator name -> its ``[[estimators]]`` entry (``path`` left out), in file order; without
    ``[[estimators]]``, a reference entry for each of ``names`` (the manifest's ``estimators``: the default
    reference estimator)."""
    entries = config.get("estimators")
    if entries is None:
        return {name: {"name": name, "kind": "reference", "parameters": {}} for name in names or ()}
    return {entry["name"]: {key: value for key, value in entry.items() if key != "path"} for entry in entries}


def _reference_users(config: dict, names: list | None, field: str) -> frozenset[str]:
    """The reference estimators of ``config`` that take ``[estimator] field`` (do not override it)."""
    return frozenset(name for name, entry in estimator_entries(config, names).items()
                     if entry.get("kind") == "reference" and field not in (entry.get("parameters") or {}))


def table_changes(old: dict, new: dict, old_names: list | None = None, new_names: list | None = None) -> list[FieldChange]:
    """The differing table fields of two resolved configurations (manifest ``config``), estimators by name
    (``old_names``, ``new_names``: the manifests' estimator names, for configurations without ``[[estimators]]``)."""
    changes = []
    old_leaves, new_leaves = _leaves(_compared_tables(old), ""), _leaves(_compared_tables(new), "")
    fields = [*old_leaves, *(name for name in new_leaves if name not in old_leaves)]
    for field in sorted(fields, key=lambda name: TABLE_ORDER.index(name.split(".")[0])
                        if name.split(".")[0] in TABLE_ORDER else len(TABLE_ORDER)):
        before, after = old_leaves.get(field, _ABSENT), new_leaves.get(field, _ABSENT)
        if before != after:
            touched = None
            table, _, key = field.partition(".")
            if table == "estimator" and key and "." not in key and key not in CALIBRATION_KEYS:
                touched = _reference_users(old, old_names, key) | _reference_users(new, new_names, key)
            changes.append(FieldChange(field, _text(before), _text(after), touched))
    old_entries, new_entries = estimator_entries(old, old_names), estimator_entries(new, new_names)
    for name in [*old_entries, *(name for name in new_entries if name not in old_entries)]:
        if name not in new_entries:
            changes.append(FieldChange(f"estimators.{name}", "(an estimator)", REMOVED, frozenset({name})))
        elif name not in old_entries:
            changes.append(FieldChange(f"estimators.{name}", "(none)", ADDED, frozenset({name})))
        else:
            index = list(new_entries).index(name)
            before, after = _leaves(old_entries[name], ""), _leaves(new_entries[name], "")
            for key in [*before, *(key for key in after if key not in before)]:
                if before.get(key, _ABSENT) != after.get(key, _ABSENT):
                    changes.append(FieldChange(f"estimators[{index}].{key} (estimator {name})",
                                               _text(before.get(key, _ABSENT)), _text(after.get(key, _ABSENT)),
                                               frozenset({name})))
    if list(old_entries) != list(new_entries) and set(old_entries) == set(new_entries):
        changes.append(FieldChange("estimators (order)", ", ".join(old_entries), ", ".join(new_entries), None))
    return changes


def input_changes(old: dict, new: dict) -> list[FieldChange]:
    """Input files and code whose digests differ, from two manifests' ``hash_inputs`` (empty when either
    manifest does not record them)."""
    before, after = old.get("hash_inputs"), new.get("hash_inputs")
    if not isinstance(before, dict) or not isinstance(after, dict):
        return []
    changes = []
    old_files, new_files = before.get("files", {}), after.get("files", {})
    for field in [*old_files, *(name for name in new_files if name not in old_files)]:
        if old_files.get(field) != new_files.get(field):
            changes.append(FieldChange(f"{field} (file bytes)", _digest(old_files.get(field)),
                                       _digest(new_files.get(field))))
    if before.get("code_digest") != after.get("code_digest"):
        changes.append(FieldChange("code (simulator, reference estimator, project plug-ins)",
                                   _digest(before.get("code_digest")), _digest(after.get("code_digest"))))
    old_code, new_code = before.get("estimator_code_digests", {}), after.get("estimator_code_digests", {})
    for key in [*old_code, *(name for name in new_code if name not in old_code)]:
        if old_code.get(key) != new_code.get(key):
            name, _, file_name = key.partition(":")
            changes.append(FieldChange(f"estimator {name}'s code ({file_name})", _digest(old_code.get(key)),
                                       _digest(new_code.get(key)), frozenset({name})))
    return changes


def _digest(value: Any) -> str:
    return f"sha256 {value[:12]}" if isinstance(value, str) and value != "missing" else "(none)"


def configuration_changes(old_manifest: dict, new_manifest: dict) -> list[FieldChange]:
    """Every difference between the configurations of two manifests (:func:`table_changes`, then
    :func:`input_changes`)."""
    tables = table_changes(old_manifest.get("config") or {}, new_manifest.get("config") or {},
                           old_manifest.get("estimators"), new_manifest.get("estimators"))
    whole = frozenset().union(*(change.estimators or frozenset() for change in tables
                                if change.new in (ADDED, REMOVED)))
    # an added or removed estimator's code is not a change of its own
    return tables + [change for change in input_changes(old_manifest, new_manifest)
                     if not (change.estimators and change.estimators <= whole)]


def only_estimators(changes: list[FieldChange]) -> frozenset[str] | None:
    """The estimators that every change touches alone (their union), or None when a change touches the
    cases' inputs (or when there is no change)."""
    if not changes or any(change.estimators is None for change in changes):
        return None
    return frozenset().union(*(change.estimators or frozenset() for change in changes))


def describe_change(old_manifest: dict, new_manifest: dict) -> str:
    """One line: what differs between a store's configuration and a submit's (module docstring).

    Parameters
    ----------
    old_manifest, new_manifest : dict
        The store's manifest and the submit's (``config``, ``config_hash``, ``hash_inputs`` when recorded).

    Returns
    -------
    str
        ``"<changes> (configuration hash a -> b)"``, then, when only some estimators changed, which ones and
        why they are not run again alone on the stored cases. No trailing advice: the caller adds what to do.
    """
    changes = configuration_changes(old_manifest, new_manifest)
    hashes = (f"configuration hash {str(old_manifest.get('config_hash', ''))[:12]} -> "
              f"{str(new_manifest.get('config_hash', ''))[:12]}")
    if not changes:
        recorded = "hash_inputs" in old_manifest and "hash_inputs" in new_manifest
        return (f"the tables are the same, so an input file's bytes (camera, trajectory set, terrain) or the code "
                f"(simulator, estimators, plug-ins) changed{'' if recorded else ' (this store does not record which)'} "
                f"({hashes})")
    shown = "; ".join(str(change) for change in changes[:SHOWN_CHANGES])
    more = f"; and {len(changes) - SHOWN_CHANGES} more" if len(changes) > SHOWN_CHANGES else ""
    text = f"{shown}{more} ({hashes})"
    names = only_estimators(changes)
    if names is not None:
        listed = ", ".join(sorted(names)) or "none"
        text += (f"; only the parameters or code of estimator {listed} changed (rendering, sensors, calibration and "
                 "the other estimators are the same), but the store keeps each case's result rows, not its rendered "
                 "images, sensor draws or calibration products, so it cannot be run again alone on the stored "
                 "cases: every case is rendered again either way")
    return text
