"""The headless LinuxCNC driver's starvation check (configs/linuxcnc-sim/driver.py, run by LinuxCNC's Python).

The driver imports LinuxCNC's ``linuxcnc`` module, which exists only in Debian's Python; its constants are given
here with the values of LinuxCNC 2.9 (``linuxcnc.EXEC_*``, ``linuxcnc.INTERP_*``) so the pure function can be
checked on any machine. The runs themselves are in tests/integration/test_linuxcnc_run.py.
"""

from __future__ import annotations

import importlib.util
import sys
import types

import pytest

from tests.conftest import REPO

DRIVER = REPO / "configs" / "linuxcnc-sim" / "driver.py"
# LinuxCNC 2.9's values (python3 -c "import linuxcnc; print(linuxcnc.EXEC_DONE, ...)")
EXEC_DONE, EXEC_WAITING_FOR_MOTION, EXEC_WAITING_FOR_MOTION_QUEUE = 2, 3, 4
EXEC_WAITING_FOR_MOTION_AND_IO, EXEC_WAITING_FOR_DELAY = 7, 8
INTERP_IDLE, INTERP_READING, INTERP_WAITING = 1, 2, 4


@pytest.fixture(scope="module")
def driver(tmp_path_factory: pytest.TempPathFactory) -> types.ModuleType:
    fake = types.ModuleType("linuxcnc")
    for name, value in {"EXEC_DONE": EXEC_DONE, "EXEC_WAITING_FOR_MOTION": EXEC_WAITING_FOR_MOTION,
                        "EXEC_WAITING_FOR_MOTION_QUEUE": EXEC_WAITING_FOR_MOTION_QUEUE,
                        "EXEC_WAITING_FOR_MOTION_AND_IO": EXEC_WAITING_FOR_MOTION_AND_IO,
                        "EXEC_WAITING_FOR_DELAY": EXEC_WAITING_FOR_DELAY, "INTERP_IDLE": INTERP_IDLE,
                        "INTERP_READING": INTERP_READING, "INTERP_WAITING": INTERP_WAITING,
                        "NML_ERROR": 11, "OPERATOR_ERROR": 13}.items():
        setattr(fake, name, value)
    saved = sys.modules.get("linuxcnc")
    sys.modules["linuxcnc"] = fake
    try:
        spec = importlib.util.spec_from_file_location("ilcnc_sim_driver", DRIVER)
        assert spec is not None and spec.loader is not None
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
    finally:
        if saved is None:
            sys.modules.pop("linuxcnc", None)
        else:
            sys.modules["linuxcnc"] = saved
    return mod


def _poll(queue: int, line: int, exec_state: int = EXEC_DONE, armed: bool = False,
          interp: int = INTERP_WAITING) -> tuple[int, int, int, int, bool]:
    return (queue, line, interp, exec_state, armed)


def test_a_queue_drained_before_a_dwell_is_not_starvation(driver: types.ModuleType) -> None:
    # the trace of the dwell test program at k = 8 (bench/linuxcnc_dwell.py): 143 blocks queued, task waits for
    # motion before the G4 (state 7) while motion drains the queue, waits out the dwell (state 8, gate armed),
    # then refills
    trace = ([_poll(143, 6)] * 5 + [_poll(q, 300, EXEC_WAITING_FOR_MOTION_AND_IO) for q in (80, 30, 3)]
             + [_poll(0, 304, EXEC_WAITING_FOR_DELAY, armed=True)] * 3 + [_poll(5, 311, EXEC_DONE, armed=True)]
             + [_poll(121, 311)] * 5 + [_poll(q, 600, EXEC_WAITING_FOR_MOTION) for q in (60, 10, 0)])
    assert driver.queue_low(trace) is None


def test_a_queue_that_runs_low_while_task_sends_is_starvation(driver: types.ModuleType) -> None:
    # task sends as fast as it can (done / waiting for queue space) and the queue still falls below 100 blocks
    # while far more lines are still to run: the planner sees less look-ahead than at k = 1
    trace = [_poll(143, 10)] * 5 + [_poll(q, 10 + i, EXEC_WAITING_FOR_MOTION_QUEUE)
                                    for i, q in enumerate((120, 90, 40))] + [_poll(100, 900)]
    assert driver.queue_low(trace) == {"queue": 90, "motion_line": 11}
