"""``campaign export DIR CASE_ID OUT``: a campaign case's exact estimator inputs as files, to replay it.

The case is simulated again from the store's manifest (its configuration as resolved) and its plan row,
with the functions a worker uses (:func:`campaign.case.inputs.campaign_inputs`,
:func:`campaign.case.compute.simulate_case_inputs`, :func:`~campaign.case.compute.estimator_inputs`,
:func:`~campaign.case.compute.case_truth`): a case is deterministic per (campaign seed, case id), so these
are the inputs its estimators got. ``OUT`` receives::

    image_1.png ... image_3.png   16-bit grey PNG of the binned DN as read out (256 x 1024 for MER); read
                                  without a declaration, a 16-bit container holds camera DN as they are
                                  (file_formats.descent_images), so the estimator gets the same uint16 array
    measurements.json             file_formats.measurements_json (exact: JSON keeps every float64 bit)
    flat_field.npy                the campaign's flat field (float32, read-out shape); only when its
                                  [estimator] flat_field gives one (a stale one in OUT is removed)
    estimator.toml                the first reference estimator's parameters as an [estimator] table (--config)
    estimators/NAME/              per estimator of the campaign (every kind), its parameters and what its
                                  replay reads and writes (below)
    truth.json                    what the estimator must not see: true velocity at the last image,
                                  altitudes, wind, attitude floor, the case's sensor errors, the plan row,
                                  and the store's result rows of the case; ``estimators``: per estimator its
                                  kind, parameters, replay command, answer file and stored row; ``replay``
                                  is the first reference estimator's command line

Each estimator's replay command (printed by ``campaign export``, in ``truth.json``) answers what the campaign
stored for that estimator on the case, bit for bit (unless the case was recorded ``outside_terrain``: the
campaign overrides any answer to invalid; ``truth.json`` says so):

``reference``  ``python -m dimes_velocity OUT/image_1.png OUT/image_2.png OUT/image_3.png OUT/measurements.json
               --camera CAMERA.toml --flat-field OUT/flat_field.npy|none --config OUT/estimators/NAME/estimator.toml``
               (the answer JSON on stdout); the estimator's parameters in ``estimator.toml``
``python``     ``env PYTHONPATH=ROOT python -m estimators.run_python MODULE:FUNCTION --measurements ... --camera
               CAMERA.toml --flat-field ... --parameters OUT/estimators/NAME/parameters.json --output
               OUT/estimators/NAME/answer.json OUT/image_1.png ...`` (:mod:`estimators.run_python`: the callable
               on the same arrays, read-only, with a deep copy of its parameters; ``ROOT`` is where the
               campaign imported its module from)
``command``    in ``OUT/estimators/NAME``, the entry's ``argv`` with ``{images}``, ``{measurements}``,
               ``{camera}``, ``{flat_field}``, ``{parameters}``, ``{output}``, ``{workdir}`` and ``{python}``
               replaced by the written files' paths exactly as a worker replaces them (:func:`estimators.command.write_inputs`: images in its
               ``image_format``, the flat field in its ``flat_field_format``, ``parameters.json``,
               ``camera.toml``), so the program reads the same files and writes ``result.json`` there

Errors (:class:`~campaign.store.errors.StoreError`, one line; nothing written): not a store, a case id
not in the plan, ``OUT`` not a writable directory. Files are written to a temporary directory beside
``OUT`` and moved in at the end.
"""
from __future__ import annotations

import importlib
import json
import os
import shlex
import shutil
import sys
import tempfile
from dataclasses import asdict, replace
from pathlib import Path

import pandas as pd
import tomli_w

from campaign.case.compute import case_truth, estimator_inputs, simulate_case_inputs
from campaign.case.inputs import PlanRow, campaign_inputs
from campaign.store.campaign_store import CampaignStore
from campaign.store.errors import StoreError
from campaign.store.stored_config import stored_config
from estimators.command import expand, write_inputs
from estimators.contract import EstimatorInputs
from estimators.entries import EstimatorSpec
from estimators.plugins import module_root
from file_formats.descent_images import write_descent_image
from file_formats.flat_field_files import save_flat_field
from file_formats.measurements_json import json_ready, measurements_to_dict

IMAGE_NAMES = ("image_1.png", "image_2.png", "image_3.png")
ESTIMATORS_DIR = "estimators"
ANSWER_NAME = "answer.json"           # a python plug-in's replayed answer (estimators.run_python --output)
FLAT_FIELD_NAME = "flat_field.npy"
#: stored result columns copied into truth.json (per estimator)
STORED_COLUMNS = ("estimator", "status", "error", "valid", "reason", "estimate_velocity_east_mps",
                  "estimate_velocity_north_mps", "velocity_error_mps", "velocity_uncertainty_mps")


def check_output_directory(out: Path) -> None:
    """``out`` is an existing writable directory, or can be created (its nearest existing ancestor is a
    writable directory); StoreError (one line) otherwise."""
    if out.exists():
        if not out.is_dir():
            raise StoreError(f"{out}: exists and is not a directory; allowed: a directory (new or existing)")
        if not os.access(out, os.W_OK | os.X_OK):
            raise StoreError(f"{out}: not writable")
        return
    ancestor = out.absolute().parent
    while not ancestor.exists():
        ancestor = ancestor.parent
    if not ancestor.is_dir() or not os.access(ancestor, os.W_OK | os.X_OK):
        raise StoreError(f"{out}: cannot be created ({ancestor} is not a writable directory)")


def estimator_replay(spec: EstimatorSpec, shared: EstimatorInputs, staging: Path, final: Path, camera_path: str,
                     has_flat: bool) -> dict:
    """Write what estimator ``spec``'s replay reads into ``staging/estimators/NAME`` and return its record for
    truth.json: name, kind, parameters, the replay command (paths under ``final``, where ``staging`` is moved)
    and where its answer appears (module docstring).

    Parameters
    ----------
    spec : EstimatorSpec
        One estimator of the campaign.
    shared : EstimatorInputs
        The case's estimator inputs (images as read out, measurements, camera, calibration products).
    staging, final : Path
        The export's temporary directory and the output directory it becomes (absolute).
    camera_path : str
        The campaign's camera TOML (absolute).
    has_flat : bool
        The export has ``flat_field.npy`` (the campaign's flat field).
    """
    directory = staging / ESTIMATORS_DIR / spec.name
    directory.mkdir(parents=True)
    here = final / ESTIMATORS_DIR / spec.name
    images = [str(final / name) for name in IMAGE_NAMES]
    flat_field = str(final / FLAT_FIELD_NAME) if has_flat else "none"
    record: dict = {"name": spec.name, "kind": spec.kind, "parameters": json_ready(spec.parameters)}
    if spec.kind == "reference":
        (directory / "estimator.toml").write_text(tomli_w.dumps({"estimator": dict(sorted(spec.parameters.items()))}))
        command = [sys.executable, "-m", "dimes_velocity", *images, str(final / "measurements.json"), "--camera",
                   camera_path, "--flat-field", flat_field, "--config", str(here / "estimator.toml")]
        return {**record, "replay": shlex.join(command), "answer": "stdout"}
    if spec.kind == "python":
        (directory / "parameters.json").write_text(json.dumps(spec.parameters, indent=1))
        module = spec.callable.split(":")[0]
        importlib.import_module(module)           # as the campaign did (its entry's path is on sys.path)
        command = [sys.executable, "-m", "estimators.run_python", spec.callable,
                   "--measurements", str(final / "measurements.json"), "--camera", camera_path,
                   "--flat-field", flat_field, "--parameters", str(here / "parameters.json"),
                   "--output", str(here / ANSWER_NAME), *images]
        roots = module_root(module)
        if roots:
            command = ["env", f"PYTHONPATH={os.pathsep.join(roots)}", *command]
        return {**record, "callable": spec.callable, "replay": shlex.join(command), "answer": str(here / ANSWER_NAME)}
    written = write_inputs(directory, replace(shared, parameters=spec.parameters), spec.image_format,
                           spec.flat_field_format)
    prefixes = sorted({str(directory), str(directory.resolve())}, key=len, reverse=True)

    def moved(value: str) -> str:
        for prefix in prefixes:
            if value.startswith(prefix):
                return str(here) + value[len(prefix):]
        return value

    values = {key: [moved(item) for item in value] if isinstance(value, list) else moved(value)
              for key, value in written.items()}
    command = expand(spec.argv, values)
    return {**record, "argv": list(spec.argv), "replay": f"cd {shlex.quote(str(here))} && {shlex.join(command)}",
            "answer": values["output"]}


def export_case(store_dir: str | Path, case_id: int, out: str | Path) -> list[Path]:
    """Write case ``case_id`` of the campaign store ``store_dir`` into ``out`` (module docstring); return
    the files written. StoreError (one line, nothing written) for a bad store, case id or ``out``."""
    store, out = CampaignStore(store_dir), Path(out)
    plan = store.plan()                             # StoreError: not a store, corrupt manifest or plan
    manifest = store.manifest() or {}
    rows = plan[plan["case_id"].astype(int) == int(case_id)]
    if rows.empty:
        ids = plan["case_id"].astype(int)
        raise StoreError(f"{store.root}: case {case_id} is not in the plan ({len(ids)} cases, ids "
                         f"{ids.min()} to {ids.max()}; `campaign status {store.root}`)")
    check_output_directory(out)
    config = stored_config(store, manifest)      # a python entry's path goes on sys.path (its module imports)
    row = PlanRow.from_record(rows.iloc[0].to_dict())
    resources = campaign_inputs(config)
    inputs = simulate_case_inputs(resources, row)
    truth = case_truth(resources, inputs)
    shared = estimator_inputs(resources, inputs)
    flat = shared.calibration.flat_field
    reference = next((spec for spec in config.estimators if spec.kind == "reference"), None)
    stored = store.results()
    stored = stored[stored["case_id"].astype(int) == row.case_id] if not stored.empty else pd.DataFrame()
    camera_path = str(Path(config.site.camera_path).resolve())
    final = out.absolute()
    replay = [sys.executable, "-m", "dimes_velocity", *(str(final / name) for name in IMAGE_NAMES),
              str(final / "measurements.json"), "--camera", camera_path,
              "--flat-field", str(final / FLAT_FIELD_NAME) if flat is not None else "none"]
    if reference is not None:
        replay += ["--config", str(final / "estimator.toml")]
    outside = max(truth.outside_terrain_fraction) > config.max_outside_terrain_fraction
    rows_by_estimator = {str(record["estimator"]): record for record in stored.to_dict("records")}
    truth_record = {
        "case_id": row.case_id, "campaign_seed": config.seed, "store": str(store.root.absolute()),
        "config_hash": config.config_hash, "config_hash_matches_store": config.config_hash == manifest["config_hash"],
        "camera": camera_path, "flat_field_source": shared.calibration.flat_field_source,
        "reference_estimator": reference.name if reference is not None else None,
        "plan": json_ready(asdict(row)),
        **{key: json_ready(value) for key, value in asdict(truth).items() if not key.startswith("t_")},
        "outside_terrain": bool(outside),
        "stored_results": [json_ready({column: record.get(column) for column in STORED_COLUMNS})
                           for record in stored.to_dict("records")],
        "replay": shlex.join(replay),
    }
    out.absolute().parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.export-", dir=out.absolute().parent))
    try:
        for name, image in zip(IMAGE_NAMES, shared.images):
            write_descent_image(staging / name, image)
        (staging / "measurements.json").write_text(json.dumps(measurements_to_dict(shared.measurements), indent=1))
        if flat is not None:
            save_flat_field(staging / FLAT_FIELD_NAME, flat)
        if reference is not None:
            parameters = dict(sorted(reference.parameters.items()))
            (staging / "estimator.toml").write_text(tomli_w.dumps({"estimator": parameters}))
        replays = [estimator_replay(spec, shared, staging, final, camera_path, flat is not None)
                   for spec in config.estimators]
        truth_record["estimators"] = [
            {**replayed, "stored": json_ready({column: rows_by_estimator.get(replayed["name"], {}).get(column)
                                               for column in STORED_COLUMNS})} for replayed in replays]
        (staging / "truth.json").write_text(json.dumps(truth_record, indent=1))
        names = sorted(path.name for path in staging.iterdir())
        if not out.exists():
            os.rename(staging, out)
        else:
            for name in names:
                if (staging / name).is_dir() and (out / name).is_dir():
                    shutil.rmtree(out / name)                       # an earlier export's estimators/
                os.replace(staging / name, out / name)
            for name in (FLAT_FIELD_NAME, "estimator.toml", ESTIMATORS_DIR):   # never leave another campaign's file
                if name not in names:
                    if (out / name).is_dir() and not (out / name).is_symlink():
                        shutil.rmtree(out / name)
                    else:
                        (out / name).unlink(missing_ok=True)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return [out / name for name in names]
