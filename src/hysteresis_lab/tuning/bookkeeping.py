"""Trial bookkeeping shared by all workers of a study: heartbeats, dead workers, the exact total.

Each trial records its worker (host, pid) and a heartbeat time in user attributes. A running
trial whose worker is gone (same host, pid not alive) or whose heartbeat is older than the
grace period is *discarded*: marked failed with ``discarded`` set, and not counted. Counting
only non-discarded trials makes a resumed or shared study run exactly ``n_trials``.
"""

from __future__ import annotations

import logging
import os
import socket
import threading
import time
from datetime import datetime

import optuna
from optuna.trial import TrialState

log = logging.getLogger(__name__)

HOST, PID, HEARTBEAT, DISCARDED = "worker_host", "worker_pid", "heartbeat", "discarded"
FINISHED = (TrialState.COMPLETE, TrialState.PRUNED, TrialState.FAIL)


def ask_claimed(study: optuna.Study) -> optuna.trial.Trial:
    """Start a trial that names this worker from its first write.

    ``study.ask()`` followed by setting the worker attributes leaves a window in which a
    killed worker leaves a running trial nobody can tell is dead until its grace period
    runs out; creating the trial from a template writes state and worker in one
    transaction, so there is no such window.
    """
    template = optuna.trial.FrozenTrial(
        number=-1,
        state=TrialState.RUNNING,
        value=None,
        datetime_start=datetime.now(),
        datetime_complete=None,
        params={},
        distributions={},
        user_attrs={HOST: socket.gethostname(), PID: os.getpid(), HEARTBEAT: time.time()},
        system_attrs={},
        intermediate_values={},
        trial_id=-1,
    )
    # The public API has no "create a running trial with attributes"; these are the steps of
    # Study.ask, which also drops the trial cache so the sampler sees the latest results.
    study._thread_local.cached_all_trials = None  # noqa: SLF001
    trial_id = study._storage.create_new_trial(study._study_id, template_trial=template)  # noqa: SLF001
    return optuna.trial.Trial(study, trial_id)


def counted(trial: optuna.trial.FrozenTrial) -> bool:
    return DISCARDED not in trial.user_attrs


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _is_stale(trial: optuna.trial.FrozenTrial, grace_s: float) -> bool:
    attrs = trial.user_attrs
    if attrs.get(HOST) == socket.gethostname() and attrs.get(PID) != os.getpid():
        return not _pid_alive(int(attrs.get(PID, -1)))
    started = trial.datetime_start.timestamp() if trial.datetime_start else time.time()
    return time.time() - float(attrs.get(HEARTBEAT, started)) > grace_s


def discard_stale(study: optuna.Study, grace_s: float) -> int:
    """Fail and discard running trials whose worker died; return how many."""
    storage = study._storage  # noqa: SLF001 - the public Study API cannot fail a foreign trial
    n = 0
    for trial in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)):
        if _is_stale(trial, grace_s):
            try:
                storage.set_trial_user_attr(trial._trial_id, DISCARDED, "worker died")  # noqa: SLF001
                storage.set_trial_state_values(trial._trial_id, TrialState.FAIL)  # noqa: SLF001
                n += 1
                log.warning(
                    "trial %d: its worker died mid-trial; it will be run again", trial.number
                )
            except RuntimeError:  # finished meanwhile
                continue
    return n


def discard(study: optuna.Study, trial: optuna.trial.Trial, reason: str) -> None:
    trial.set_user_attr(DISCARDED, reason)
    study.tell(trial, state=TrialState.FAIL)


def progress(study: optuna.Study) -> tuple[int, int]:
    """(finished, running) trials that count towards ``n_trials``."""
    trials = [t for t in study.get_trials(deepcopy=False) if counted(t)]
    finished = sum(t.state in FINISHED for t in trials)
    running = sum(t.state == TrialState.RUNNING for t in trials)
    return finished, running


def is_surplus(study: optuna.Study, trial: optuna.trial.Trial, n_trials: int) -> bool:
    """True when ``n_trials`` counted trials were already asked before this one."""
    earlier = [
        t
        for t in study.get_trials(deepcopy=False)
        if t.number < trial.number and counted(t) and t.state != TrialState.WAITING
    ]
    return len(earlier) >= n_trials


class Heartbeat:
    """Refresh a trial's heartbeat attribute from a daemon thread while it runs."""

    def __init__(self, trial: optuna.trial.Trial, interval_s: float) -> None:
        self.trial, self.interval_s = trial, interval_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._beat, daemon=True)

    def __enter__(self) -> Heartbeat:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()

    def _beat(self) -> None:
        while not self._stop.wait(self.interval_s):
            try:
                self.trial.set_user_attr(HEARTBEAT, time.time())
            except Exception:  # the trial finished or the storage blinked; try again later
                log.debug("heartbeat of trial %d failed", self.trial.number, exc_info=True)
