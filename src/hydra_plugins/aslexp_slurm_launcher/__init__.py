"""hydra-submitit-launcher's Slurm launcher, with a memory request that no node can satisfy said in
one line that names ``hydra.launcher.mem_gb`` (selected by conf/hydra/launcher/slurm.yaml).

Before submitting, the request is compared with the largest node of the partition (``sinfo``): a
request above it stops the run before any job is queued, with the size that fits. Where ``sinfo``
cannot answer, Slurm's own refusal ("Memory specification can not be satisfied") gets the same
hint. Either is a :class:`~aslexp.tuning.worker.LaunchRefused` (a ConfigError: exit 2); the
Optuna sweeper stops on it with the trial not counted, so the same command with a smaller
``mem_gb`` resumes the study.
"""

from __future__ import annotations

import shutil
import subprocess
from collections.abc import Sequence
from typing import Any

from hydra.core.utils import JobReturn
from hydra_plugins.hydra_submitit_launcher.submitit_launcher import SlurmLauncher

# What sbatch says when no node of the partition has the memory asked for.
SLURM_MEMORY_REFUSALS = ("Memory specification can not be satisfied", "Requested node configuration is not available")


def largest_node_memory_mb(partition: str | None) -> int | None:
    """RealMemory (MB) of the partition's largest node, from ``sinfo``; None where it cannot say."""
    if shutil.which("sinfo") is None:
        return None
    command = ["sinfo", "-h", "-o", "%m", *(["-p", partition] if partition else [])]
    try:
        out = subprocess.run(command, capture_output=True, text=True, timeout=20).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    sizes = [int(value.rstrip("+")) for value in out.split() if value.rstrip("+").isdigit()]
    return max(sizes) if sizes else None


def memory_hint(mem_gb: Any, partition: str | None, largest_mb: int | None, slurm_said: str = "") -> str:
    where = f"partition {partition!r}" if partition else "the default partition"
    fits = "set a smaller hydra.launcher.mem_gb"
    if largest_mb:
        fits = (f"the largest node of {where} has {largest_mb} MB: "
                f"set hydra.launcher.mem_gb={max(1, largest_mb // 1024)} or less")
    said = f" (Slurm: {' '.join(slurm_said.split())})" if slurm_said else ""
    return (f"hydra.launcher.mem_gb={mem_gb}: Slurm cannot give a job {mem_gb} GB on {where}; {fits} "
            f"(null: Slurm's default); nothing was submitted{said}")


class AslexpSlurmLauncher(SlurmLauncher):
    def launch(self, job_overrides: Sequence[Sequence[str]], initial_job_idx: int) -> Sequence[JobReturn]:
        from aslexp.tuning.worker import LaunchRefused  # here: Hydra imports every plugin at each start

        mem_gb, partition = self.params.get("mem_gb"), self.params.get("partition")
        if mem_gb is not None:
            largest = largest_node_memory_mb(partition)
            if largest is not None and float(mem_gb) * 1024 > largest:
                raise LaunchRefused(memory_hint(mem_gb, partition, largest))
        try:
            return super().launch(job_overrides, initial_job_idx)
        except Exception as err:  # submitit's FailedJobError carries sbatch's stderr
            text = str(err)
            if mem_gb is not None and any(refusal in text for refusal in SLURM_MEMORY_REFUSALS):
                raise LaunchRefused(memory_hint(mem_gb, partition, largest_node_memory_mb(partition), text)) from None
            raise
