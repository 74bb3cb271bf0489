#!/usr/bin/python3
"""Headless "display" for the ilcnc LinuxCNC simulation: run one program, log it, exit.

The ``linuxcnc`` launcher starts this as ``./driver.py -ini <inifile>`` (see
``[DISPLAY] DISPLAY`` in sim.ini) once HAL, task and IO are up, and shuts
LinuxCNC down when it exits; its exit code becomes the launcher's. It must run
under Debian's /usr/bin/python3 (the ``linuxcnc`` module exists only there).

Sequence: E-stop reset, machine on, home all joints (in place), open the
program, start ``halsampler -t LOG``, run the program in AUTO with motion held
(``motion.feed-inhibit``) until task has queued the first blocks (200, or all
of a shorter program), release the
hold and enable the sampler in the same servo cycle (HAL signal ``ilcnc-go``),
hold each restart after a dwell the same way (the dwell gate, see
``Dwells``), wait until the interpreter is idle, the motion queue empty and
motion done, keep sampling ILCNC_SETTLE more seconds (wall clock; the axes still lag
after ``motion.program-line`` went back to 0), disable the sampler, drain the
FIFO, stop halsampler, switch the machine off, write the result file, exit.

Environment
-----------
ILCNC_PROGRAM          absolute path of the G-code program (required)
ILCNC_LOG              absolute path of the halsampler output (required)
ILCNC_RESULT           path of the JSON result file (optional)
ILCNC_SETTLE           wall-clock seconds sampled after the program is done (default 0.3)
ILCNC_TIMEOUT          wall-clock limit for the program itself, s (default 600)
ILCNC_HOLD             longest wall-clock time motion is held at the start while
                       task queues blocks, s (default 2; released as soon as
                       ILCNC_HOLD_QUEUE blocks are queued or the queue stops
                       growing for 50 ms)
ILCNC_HOLD_QUEUE       blocks to queue before motion starts (default 200; motion
                       accepts one block per servo cycle, so this costs up to
                       0.2 s at 1 ms)

Result file (JSON object)
-------------------------
``status``: ``"ok"`` or ``"error"``; ``errors``: error-channel errors, each
``{"kind": int, "text": str}``; ``messages``: other error-channel texts;
``line``: on an error, the interpreter's line (``stat.read_line``, 1-based,
0 if unknown) and ``motion_line`` (the block executing when motion stopped);
``task_state``: task state at the end (4 = ON; 2 = a following error switched
the machine off); ``program_wall_s``: wall time from AUTO_RUN to done;
``phase``: where it stopped; ``queue_low``: null, or the queue depth and line
at which the motion queue ran low while task still had blocks to send (the
planner then saw less look-ahead than in a real-time run); ``dwells``:
``{"held": n, "missed": n, "held_wall_s": s}``, the restarts after stops (a
dwell, a queue-busting block) the gate held until task had queued the next
blocks, the restarts it could not hold (0: the gate arms itself in HAL), and
the wall time the driver held them.

Exit code: 0 = program ran without errors, 1 = LinuxCNC reported an error
(interpreter refused the program, following error, ...), 2 = the driver
itself failed (timeout, LinuxCNC did not come up).
"""

import json
import os
import signal
import subprocess
import sys
import time

import linuxcnc

T0 = time.monotonic()
ERROR_KINDS = (linuxcnc.NML_ERROR, linuxcnc.OPERATOR_ERROR)

result = {"status": "error", "phase": "start", "errors": [], "messages": [], "line": 0, "motion_line": 0,
          "task_state": 0, "program_wall_s": None}


def say(*a):
    print("[driver %7.3f]" % (time.monotonic() - T0), *a, file=sys.stderr, flush=True)


def halcmd(*args):
    return subprocess.run(["halcmd", *args], check=True, capture_output=True, text=True).stdout.strip()


def hal_int(name):
    """An integer HAL pin (note: sampler.N.sample-num stays 0 in 2.9; halsampler -t counts itself)."""
    return int(float(halcmd("getp", name)))


# task's execution states in which it sends blocks as fast as it can (a low queue then is starvation)
SENDING = (linuxcnc.EXEC_DONE, linuxcnc.EXEC_WAITING_FOR_MOTION_QUEUE)
# ... and those in which it waits for motion to stop and then for a dwell: the restart after them is held
STOPPING = (linuxcnc.EXEC_WAITING_FOR_MOTION, linuxcnc.EXEC_WAITING_FOR_MOTION_AND_IO,
            linuxcnc.EXEC_WAITING_FOR_DELAY)


def queue_low(trace, low=100, slack=20):
    """First poll at which the motion queue ran low while task still had blocks to send, or None.

    The trajectory planner only looks ahead over what is queued; if task
    cannot keep the queue filled (a time-scaled run of many short blocks),
    motion slows down or waits and the log differs from a real-time run.
    At the natural end the queue drains too, so a low queue counts only when
    more lines ran afterwards than were queued (lines increasing); with
    lines going backwards (loops) only while the interpreter was still reading.
    """
    lines = [t[1] for t in trace if t[1] > 0]
    if not lines:
        return None
    monotone = all(b >= a for a, b in zip(lines, lines[1:]))
    final = max(lines)
    for q, m, st, ex, armed in trace:
        if m <= 0 or q >= low or armed or ex not in SENDING:
            continue  # task waits on purpose (a dwell, a queue-busting block, the end): motion drains the queue
        if (monotone and final - m > q + slack) or (not monotone and st == linuxcnc.INTERP_READING and q < 10):
            return {"queue": q, "motion_line": m}
    return None


class QueueFill:
    """When task has queued what it will queue before motion starts (the rule of the start gate and the dwell gate).

    ``hold_queue`` blocks (far more than the planner's look-ahead, 40 blocks in 2.9), or a queue that has not
    grown for :attr:`QUIET_S` (all queued, or the interpreter waits for motion).
    """

    QUIET_S = 0.05

    def __init__(self, hold_queue):
        self.hold_queue = hold_queue
        self.last_q = -1
        self.t_q = time.monotonic()

    def done(self, queue):
        """Poll with the queue's depth now: True once it is filled."""
        now = time.monotonic()
        if queue != self.last_q:
            self.last_q, self.t_q = queue, now
            return queue >= self.hold_queue
        return queue >= self.hold_queue or (queue > 0 and now - self.t_q > self.QUIET_S)


class Dwells:
    """The dwell gate: a restart after a stop starts with the queue filled, as the program's start does.

    Task runs a dwell (G4) in wall-clock time after motion has stopped, then
    sends the next blocks one per task cycle; motion starts on the first one.
    How many blocks the planner sees when it starts then depends on the time
    scale (task's 1 ms is k servo cycles). The driver keeps the gate's request
    (``ilcnc-dwell``) on from the start of motion: HAL arms the gate by itself
    whenever motion comes to rest with an empty queue (a dwell, a queue-busting
    block, the end), so no timing of the driver's can miss a stop. Once armed,
    motion is held, and in the servo cycle the next block arrives the whole
    simulated world stops (drives and sampler). The driver sees the world
    frozen, waits until task has queued what it will queue, and releases it
    (the request off for a moment, then on again): the world goes on from the
    same state, and the log shows the dwell and then a start with full
    look-ahead, at any time scale.
    """

    def __init__(self):
        self.on = False
        self.stopped = False  # from task's first wait for motion to the restart: a low queue is no starvation
        self.seen = 0  # restarts the gate held
        self.missed = 0  # kept for the result's format: with the request always on, none can be missed
        self.held_wall_s = 0.0
        self.t_hold = None
        self.fill = None

    def start(self):
        halcmd("sets", "ilcnc-dwell", "1")
        self.on = True

    def stop(self):
        if self.on:
            halcmd("sets", "ilcnc-dwell", "0")
            self.on = False

    def step(self, s, hold_queue):
        """One poll: if the world is frozen at a restart, release it once the queue is filled."""
        if s.exec_state in STOPPING:
            self.stopped = True  # task waits for motion (and then a dwell): the queue drains on purpose
        if not self.on or s.queue == 0:
            return
        # held motion does not move; in motion the speed is zero only for an instant, so HAL is asked only then
        if self.t_hold is None and (s.current_vel > 0.0 or halcmd("getp", "ilcnc.frozen.out") != "TRUE"):
            if s.current_vel > 0.0 and s.exec_state not in STOPPING:
                self.stopped = False
            return
        if self.t_hold is None:
            self.t_hold, self.fill = time.monotonic(), QueueFill(hold_queue)
        if self.fill.done(s.queue):
            halcmd("sets", "ilcnc-dwell", "0")  # resets the flip-flop: the world goes on in the next cycle
            halcmd("sets", "ilcnc-dwell", "1")  # motion moves now: armed again only at the next stop
            self.seen += 1
            self.held_wall_s += time.monotonic() - self.t_hold
            self.t_hold = None
            self.stopped = False

    def report(self):
        return {"held": self.seen, "missed": self.missed, "held_wall_s": round(self.held_wall_s, 3)}


class Stop(Exception):
    """The driver gives up (timeout, signal); the message goes into the result."""


def on_signal(signum, frame):
    raise Stop("driver received signal %d" % signum)


def main():
    program = os.path.abspath(os.environ["ILCNC_PROGRAM"])
    log = os.path.abspath(os.environ["ILCNC_LOG"])
    settle = float(os.environ.get("ILCNC_SETTLE", "0.3"))
    hold = float(os.environ.get("ILCNC_HOLD", "2.0"))
    hold_queue = int(os.environ.get("ILCNC_HOLD_QUEUE", "200"))
    timeout = float(os.environ.get("ILCNC_TIMEOUT", "600"))
    # what the user asked for (--timeout is machine time; at time scale k the wall-clock limit is that / k)
    timeout_label = os.environ.get("ILCNC_TIMEOUT_LABEL", "the %.1f s timeout" % timeout)

    s = linuxcnc.stat()
    c = linuxcnc.command()
    e = linuxcnc.error_channel()

    def poll_errors():
        """Drain the error channel; return True if an error arrived."""
        got = False
        while True:
            msg = e.poll()
            if not msg:
                return got
            kind, text = msg
            text = " ".join(str(text).split())
            say("error channel:", kind, text)
            if kind in ERROR_KINDS:
                result["errors"].append({"kind": kind, "text": text})
                got = True
            else:
                result["messages"].append(text)

    def wait(pred, seconds, what):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            s.poll()
            if pred():
                return
            poll_errors()
            time.sleep(0.005)
        raise Stop("timeout after %.1f s waiting for %s" % (seconds, what))

    # task may not answer the instant the display starts
    end = time.monotonic() + 10
    while True:
        try:
            s.poll()
            break
        except linuxcnc.error:
            if time.monotonic() > end:
                raise Stop("LinuxCNC task did not answer within 10 s") from None
            time.sleep(0.01)

    result["phase"] = "machine on"
    c.state(linuxcnc.STATE_ESTOP_RESET)
    c.wait_complete()
    c.state(linuxcnc.STATE_ON)
    c.wait_complete()
    wait(lambda: s.task_state == linuxcnc.STATE_ON, 10, "machine on")
    result["phase"] = "homing"
    c.mode(linuxcnc.MODE_MANUAL)
    c.wait_complete()
    c.teleop_enable(0)
    c.wait_complete()
    c.home(-1)
    c.wait_complete()
    wait(lambda: all(s.homed[j] for j in range(s.joints)), 20, "homing")
    say("homed")
    poll_errors()
    result["errors"].clear()  # nothing before the program counts

    result["phase"] = "open"
    c.mode(linuxcnc.MODE_AUTO)
    c.wait_complete()
    c.program_open(program)
    c.wait_complete()
    if poll_errors():
        result["phase"] = "open failed"
        return 1

    hs = subprocess.Popen(["halsampler", "-t", log])
    try:
        time.sleep(0.05)
        result["phase"] = "run"
        say("run", program)
        t_run = time.monotonic()
        c.auto(linuxcnc.AUTO_RUN, 0)
        # motion is held (feed-inhibit) until task has queued the first blocks
        hold_end = time.monotonic() + hold
        fill = QueueFill(hold_queue)
        while time.monotonic() < hold_end:
            s.poll()
            if poll_errors() or fill.done(s.queue):
                break
            time.sleep(0.002)
        say("release with %d queued" % fill.last_q)
        halcmd("sets", "ilcnc-go", "1")
        t_release = time.monotonic()
        started = False
        trace = []  # (queue depth, motion_line, interp_state, exec_state, stopped or held at a restart) per poll, for the starvation check
        dw = Dwells()
        dw.start()
        while True:
            s.poll()
            dw.step(s, hold_queue)
            trace.append((s.queue, s.motion_line, s.interp_state, s.exec_state, dw.stopped or dw.t_hold is not None))
            err = poll_errors()
            if err and not result["line"]:
                result["line"] = s.read_line
                result["motion_line"] = s.motion_line
            if s.interp_state != linuxcnc.INTERP_IDLE:
                started = True
            if started and s.interp_state == linuxcnc.INTERP_IDLE and s.queue == 0 and s.exec_state == linuxcnc.EXEC_DONE:
                break
            if not started:
                if result["errors"]:
                    break  # refused before it started (the interpreter reads ahead)
                if (time.monotonic() - t_release > 1.0 and s.queue == 0 and s.exec_state == linuxcnc.EXEC_DONE
                        and s.interp_state == linuxcnc.INTERP_IDLE):
                    break  # nothing to run (no motion at all) or over before it was seen
                if time.monotonic() - t_run > 10:
                    raise Stop("program did not start within 10 s")
            if s.task_state != linuxcnc.STATE_ON and started:
                break  # e.g. following error: machine switched off
            if time.monotonic() - t_run > timeout:
                raise Stop("program still running after %s" % timeout_label)
            time.sleep(0.002)
        dw.stop()
        result["dwells"] = dw.report()
        result["program_wall_s"] = round(time.monotonic() - t_run, 4)
        result["queue_low"] = queue_low(trace)
        if os.environ.get("ILCNC_TRACE"):
            result["trace"] = trace
        result["task_state"] = s.task_state
        say("program done in %.3f s wall, task_state %d" % (result["program_wall_s"], s.task_state))

        result["phase"] = "settle"
        time.sleep(settle)
        halcmd("sets", "ilcnc-go", "0")  # sampler off (and feed-inhibit on again: nothing moves now)
        result["phase"] = "drain"
        end = time.monotonic() + 20
        while hal_int("sampler.0.curr-depth") > 0:
            if time.monotonic() > end:
                raise Stop("halsampler did not drain the FIFO")
            time.sleep(0.01)
        time.sleep(0.1)  # let halsampler write its last line
        poll_errors()
    finally:
        hs.terminate()
        try:
            hs.wait(5)
        except subprocess.TimeoutExpired:
            hs.kill()
            hs.wait()
    s.poll()
    result["task_state"] = s.task_state
    if s.task_state == linuxcnc.STATE_ON:
        c.state(linuxcnc.STATE_OFF)
        c.wait_complete()
    result["phase"] = "done"
    if result["errors"]:
        return 1
    result["status"] = "ok"
    return 0


if __name__ == "__main__":
    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    try:
        code = main()
    except Stop as exc:
        result["errors"].append({"kind": -1, "text": str(exc)})
        say("stop:", exc)
        code = 2
    except Exception as exc:  # noqa: BLE001 - report anything to the caller
        result["errors"].append({"kind": -2, "text": "%s: %s" % (type(exc).__name__, exc)})
        say("failed:", repr(exc))
        code = 2
    path = os.environ.get("ILCNC_RESULT")
    if path:
        with open(path + ".tmp", "w") as f:
            json.dump(result, f, indent=1)
        os.replace(path + ".tmp", path)
    sys.exit(code)
