"""Inputs a driver loaded and shipped to its workers, held here (pickled) until the process's cases take them.

Light on purpose (standard library only): a dask worker stores what arrives as it joins
(:class:`campaign.run.worker_startup.ShippedInputs`) without importing the simulator; the first
:func:`campaign.case.inputs.campaign_inputs` of the process unpickles it into the process's
:class:`~campaign.case.inputs.SharedInputs`, where it stands for what the worker would otherwise load under the
same keys (:func:`campaign.case.inputs.shippable_inputs` says which).
"""
from __future__ import annotations

_RECEIVED: list[bytes] = []


def receive(payload: bytes) -> None:
    """Keep ``payload`` (a pickled dict of SharedInputs entries) for :func:`take`."""
    _RECEIVED.append(payload)


def take() -> list[bytes]:
    """The payloads received since the last call, oldest first (each is taken once)."""
    payloads = list(_RECEIVED)
    _RECEIVED.clear()
    return payloads
