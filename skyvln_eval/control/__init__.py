"""Control: one :class:`Controller` interface, the paper's NMPC, linear MPC and cascaded PID,
and the closed loop that flies them on the simulated drone.

- :func:`make_controller` / :func:`load_controller`: ``"nmpc"``, ``"mpc"`` (linear) or
  ``"pid"`` by name, with settings from a mapping or ``configs/controllers/*.yaml``;
- :class:`Flight` / :func:`fly_to`: fly a target pose (or any reference) through an
  obstacle scenario, segment after segment, on one deterministic clock;
- :data:`LOG_COLUMNS`, :func:`save_flight_log`, :func:`load_flight_log`: the per-step log;
- :func:`record_paper_runs`: the static- and dynamic-obstacle runs behind the paper's figures.

Importing this package imports CasADi.
"""

from skyvln_eval.control.base import Command, Controller, SolveStats
from skyvln_eval.control.closed_loop import ArrivalCriteria, Flight, SegmentResult, fly_to
from skyvln_eval.control.flight_log import (
    LOG_COLUMNS,
    LOG_FORMAT_VERSION,
    load_flight_log,
    log_frame,
    save_flight_log,
)
from skyvln_eval.control.mpc import LinearMpcController, NmpcController
from skyvln_eval.control.mpc_config import MpcConfig, MpcWeights
from skyvln_eval.control.pid import PidConfig, PidController
from skyvln_eval.control.recordings import PAPER_CASES, record_paper_runs
from skyvln_eval.control.registry import (
    config_from_mapping,
    controller_config,
    controller_names,
    load_controller,
    make_controller,
)

__all__ = [
    "LOG_COLUMNS",
    "LOG_FORMAT_VERSION",
    "PAPER_CASES",
    "ArrivalCriteria",
    "Command",
    "Controller",
    "Flight",
    "LinearMpcController",
    "MpcConfig",
    "MpcWeights",
    "NmpcController",
    "PidConfig",
    "PidController",
    "SegmentResult",
    "SolveStats",
    "config_from_mapping",
    "controller_config",
    "controller_names",
    "fly_to",
    "load_controller",
    "load_flight_log",
    "log_frame",
    "make_controller",
    "record_paper_runs",
    "save_flight_log",
]
