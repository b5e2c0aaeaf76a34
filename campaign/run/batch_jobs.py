"""Batch jobs of the ``slurm`` and ``pbs`` backends: submitted, watched until a worker connects, and every
failure of the batch system told in one line naming the command and its error.

dask-jobqueue submits a job per worker group from the scheduler's event loop; a failing submission there
is logged as pages of tracebacks, again at every scaling, while the run waits ``no_workers_timeout_s``
for workers that never come. Here instead:

- the submit command (``sbatch`` / ``qsub``) missing from PATH stops the run before anything starts;
- each job's submission is recorded by :func:`recording_job_class` (its id, or its one-line error;
  nothing is logged); its job script is written readable only by its owner (mode 0600, in a private
  directory) and removed after submission;
- :func:`wait_for_first_worker` returns when the first dask worker connects and stops the run
  (:class:`~campaign.run.faults.RunStopped`) as soon as every job is known to be dead: rejected by the
  submit command, ended before its worker connected (SLURM: ``squeue`` state, last line of the job's
  output), or pending for a reason that never clears by itself (SLURM: ``squeue`` reasons in
  :data:`NEVER_STARTS`, e.g. ``PartitionConfig``: the job asks more than the partition has); or when no
  worker connected within ``[execution] no_workers_timeout_s``.

The watch polls ``squeue`` every :data:`SQUEUE_POLL_S` seconds, so a dead SLURM job stops the run within
a few seconds; PBS jobs are watched through their submission and the timeout only.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from distributed.deploy.spec import ProcessInterface

from campaign.run.faults import RunStopped

SUBMIT_COMMANDS = {"slurm": "sbatch", "pbs": "qsub"}
SQUEUE_POLL_S = 2.0
WAIT_POLL_S = 0.2
COMMAND_TIMEOUT_S = 20.0
NOTHING_RUN = "nothing was run or changed"

#: squeue reasons of a pending job that never starts unless someone changes it -> what to change
NEVER_STARTS = {
    "PartitionConfig": "the job asks more than the partition offers: lower [execution.slurm] cores, memory or "
                       "walltime (sinfo shows the nodes), or choose another queue",
    "PartitionTimeLimit": "[execution.slurm] walltime is above the partition's limit: lower it",
    "PartitionNodeLimit": "the job asks more nodes than the partition allows: check [execution.slurm] job_extra",
    "PartitionDown": "the partition is down: choose another [execution.slurm] queue or ask the administrators",
    "PartitionInactive": "the partition is inactive: choose another [execution.slurm] queue",
    "BadConstraints": "no node matches the job's constraints: check [execution.slurm] job_extra",
    "JobHeldUser": "the job is held: remove --hold from [execution.slurm] job_extra (or scontrol release it)",
    "JobHeldAdmin": "an administrator holds the job: ask them",
    "DependencyNeverSatisfied": "its dependency can never be satisfied: check [execution.slurm] job_extra",
    "InvalidAccount": "the account is not valid: check [execution.slurm] account",
    "InvalidQOS": "the QOS is not valid: check [execution.slurm] job_extra",
}
#: squeue states of a job that has ended
ENDED_STATES = frozenset({"COMPLETED", "FAILED", "CANCELLED", "TIMEOUT", "NODE_FAIL", "OUT_OF_MEMORY", "BOOT_FAIL",
                          "DEADLINE", "PREEMPTED", "SPECIAL_EXIT", "REVOKED"})


@dataclass
class JobRecord:
    """What the submissions of one cluster gave: job ids, and one line per rejected submission."""

    submitted: list[str] = field(default_factory=list)
    rejected: list[str] = field(default_factory=list)


def require_submit_command(kind: str) -> None:
    """Stop before anything starts when the batch system's submit command is not on PATH."""
    command = SUBMIT_COMMANDS[kind]
    if shutil.which(command) is None:
        raise RunStopped(f"cannot submit {kind.upper()} jobs: {command} is not on PATH; run campaign submit where "
                         f"{command} works (a login node), or choose another [execution] cluster; {NOTHING_RUN}")


def recording_job_class(base: type[ProcessInterface], record: JobRecord) -> type:
    """A subclass of dask-jobqueue's job class ``base`` whose submissions are recorded in ``record``; a
    rejected one becomes a job slot without a job (its error is ours to report, in one line)."""

    async def start(self) -> None:
        try:
            await base.start(self)
        except Exception as exc:   # any submission error is reported by wait_for_first_worker
            record.rejected.append(submission_error(self.submit_command, exc))
            await ProcessInterface.start(self)      # marks the slot running: no retry, no traceback
        else:
            record.submitted.append(str(self.job_id))

    @contextmanager
    def job_file(self) -> Iterator[str]:
        """The job script in a new private directory (0700), the file 0600 (dask-jobqueue's own is world-readable)."""
        directory = tempfile.mkdtemp(prefix="moc2dimes-job-")
        path = os.path.join(directory, "job.sh")
        try:
            descriptor = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
            with os.fdopen(descriptor, "w") as handle:
                handle.write(self.job_script())
            yield path
        finally:
            shutil.rmtree(directory, ignore_errors=True)

    return type(f"Recording{base.__name__}", (base,), {"start": start, "job_file": job_file})


def submission_error(submit_command: str, exc: BaseException) -> str:
    """One line for a failed submission: the command and its error (stderr lines, or the exception)."""
    command = submit_command.split()[0]
    text = str(exc)
    if isinstance(exc, RuntimeError) and "stderr:" in text:
        code = next((line.split(":", 1)[1].strip() for line in text.splitlines() if line.startswith("Exit code:")), "?")
        errors = [line.strip() for line in text.split("stderr:", 1)[1].splitlines() if line.strip()]
        detail = " / ".join(dict.fromkeys(errors)) or "no message"
        return f"{command} rejected the worker job (exit {code}): {detail[:400]}"
    if isinstance(exc, FileNotFoundError):
        return f"{command} could not be run: {exc.strerror} ({command} not on PATH?)"
    first = " ".join(text.split())[:300]
    return f"{command} failed: {type(exc).__name__}: {first}"


def squeue_states(job_ids: list[str]) -> dict[str, tuple[str, str]] | None:
    """Job id -> (state, reason) from ``squeue`` (jobs it no longer knows are absent); None when squeue
    itself fails (the watch then relies on the timeout)."""
    try:
        result = subprocess.run(["squeue", "-h", "-t", "all", "-j", ",".join(job_ids), "-o", "%i|%T|%r"],
                                capture_output=True, text=True, timeout=COMMAND_TIMEOUT_S)
    except (OSError, subprocess.TimeoutExpired):
        return None
    if result.returncode != 0:
        # squeue exits 1 for "Invalid job id specified" when every job has been purged
        return {} if "Invalid job id" in result.stderr else None
    states = {}
    for line in result.stdout.splitlines():
        parts = line.strip().split("|")
        if len(parts) == 3:
            states[parts[0]] = (parts[1], parts[2])
    return states


def job_output_tail(job_id: str) -> str:
    """The last non-empty line of a SLURM job's output file ("" when unknown or unreadable)."""
    try:
        shown = subprocess.run(["scontrol", "show", "job", "-o", job_id], capture_output=True, text=True,
                               timeout=COMMAND_TIMEOUT_S).stdout
    except (OSError, subprocess.TimeoutExpired):
        return ""
    path = next((item.split("=", 1)[1] for item in shown.split() if item.startswith("StdOut=")), "")
    try:
        lines = [line.strip() for line in Path(path).read_text(errors="replace").splitlines() if line.strip()] if path else []
    except OSError:
        return ""
    return f"; its output {path} ends: {lines[-1][:200]}" if lines else ""


def dead_slurm_jobs(job_ids: list[str]) -> dict[str, str] | None:
    """Job id -> one line, for the jobs that ended or never start (None when squeue cannot tell)."""
    states = squeue_states(job_ids)
    if states is None:
        return None
    dead = {}
    for job_id in job_ids:
        state, reason = states.get(job_id, ("GONE", ""))
        if state == "PENDING" and reason in NEVER_STARTS:
            dead[job_id] = (f"SLURM job {job_id} can never start: squeue reports it PENDING ({reason}); "
                            f"{NEVER_STARTS[reason]}")
        elif state in ENDED_STATES or state == "GONE":
            what = "is no longer known to squeue" if state == "GONE" else f"ended ({state})"
            dead[job_id] = f"SLURM job {job_id} {what} before its dask worker connected{job_output_tail(job_id)}"
    return dead


def wait_for_first_worker(cluster, kind: str, record: JobRecord, timeout_s: float) -> None:
    """Return when the first dask worker of ``cluster`` has connected; raise RunStopped (one line) when
    every submitted job is dead or after ``timeout_s`` seconds without a worker."""
    start = time.monotonic()
    last_poll = 0.0
    dead: dict[str, str] = {}
    while True:
        if cluster.scheduler_info.get("workers"):
            return
        expected = len(cluster.worker_spec)
        now = time.monotonic()
        if kind == "slurm" and record.submitted and now - last_poll >= SQUEUE_POLL_S:
            last_poll = now
            dead = dead_slurm_jobs(list(record.submitted)) or dead
        problems = record.rejected + list(dead.values())
        if expected and len(problems) >= expected:
            others = f" (and {len(problems) - 1} more jobs)" if len(problems) > 1 else ""
            raise RunStopped(f"{problems[0]}{others}; {NOTHING_RUN}")
        if now - start > timeout_s:
            jobs = ", ".join(record.submitted) or "none"
            raise RunStopped(f"no dask worker connected within {timeout_s:g} s of submitting the {kind.upper()} "
                             f"jobs (ids: {jobs}); check them ({'squeue' if kind == 'slurm' else 'qstat'}) or raise "
                             f"[execution] no_workers_timeout_s; {NOTHING_RUN}")
        time.sleep(WAIT_POLL_S)
