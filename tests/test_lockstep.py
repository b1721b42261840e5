"""Lockstep time (`drivers.clock.SteppedClock`): time moves only when every thread that takes part
waits, and a session on the virtual bench is the same whatever the host's speed.

The clock's rules are tested with plain threads whose work is slowed by random wall-clock delays
(what a busy host does): what each thread sees at each clock instant must not change. Then the
real station: the same seeded rotary session recorded twice on the virtual bench, once with the
host slowed by CPU hogs, gives identical sample arrays, table states and events."""

import multiprocessing
import random
import threading
import time

import h5py
import numpy as np
import pytest
from signal_places import ends, interrupted_at

import drivers.clock
import drivers.clock_link
from drivers.clock import ScaledClock, SteppedClock, WallClock
from station.protocols.rotary import RotarySettings, suggested_axes
from station.twin.rotary_bench import VirtualBench, record_rotary

CLOCK_CODE = (drivers.clock.__file__, drivers.clock_link.__file__, threading.__file__)
"""Where a Ctrl-C is raised in the clock tests: the clocks' and `threading`'s code."""


def _threads(clock, *targets, producer=()):
    """Threads of `targets`, every one enlisted before any starts (as the recorder enlists its
    reader and the protocol's thread), started; `producer`: the indices of the producers."""
    threads = [threading.Thread(target=t, daemon=True) for t in targets]
    for k, thread in enumerate(threads):
        clock.enlist(thread, producer=k in producer)
    for thread in threads:
        thread.start()
    return threads


def test_time_stands_still_without_a_station_thread():
    """A twin alone (a producer) never moves time, however long it waits."""
    clock = SteppedClock(start=5.0, step=0.1)
    stop = threading.Event()
    (producer,) = _threads(clock, lambda: [clock.pace(stop) for _ in range(3)], producer=(0,))
    producer.join(0.5)
    assert producer.is_alive() and clock.now() == 5.0
    stop.set()
    producer.join(5)
    assert not producer.is_alive() and clock.now() == 5.0


def test_time_jumps_to_the_earliest_sleeper_and_wakes_each_at_its_instant():
    clock = SteppedClock(step=1.0)
    seen = []
    lock = threading.Lock()

    def sleeper(dt, times):
        for _ in range(times):
            clock.sleep(dt)
            with lock:
                seen.append((round(clock.now(), 9), dt))

    threads = _threads(clock, lambda: sleeper(0.3, 4), lambda: sleeper(0.5, 2))
    for t in threads:
        t.join(10)
    assert sorted(seen) == [(0.3, 0.3), (0.5, 0.5), (0.6, 0.3), (0.9, 0.3), (1.0, 0.5),
                            (1.2, 0.3)]
    assert clock.now() == pytest.approx(1.2)


def _producer_consumer(clock, delays: random.Random, steps: int = 40) -> list:
    """A producer appends one item per step (`pace`), then nudges; a consumer idles until the item
    of the present instant is there and records (instant, items it saw). Random wall delays
    everywhere, as a busy host would make them."""
    items, log, stop = [], [], threading.Event()
    guard = threading.Lock()

    def jitter():
        time.sleep(delays.random() * 0.002)

    def produce():
        while not stop.is_set():
            clock.pace(stop)
            jitter()
            with guard:
                items.append(round(clock.now(), 9))
            clock.nudge()

    def consume():
        for _ in range(steps):
            clock.sleep(clock.step * 0.5)  # wake half-way between two deliveries
            jitter()
            target = round(clock.now() + clock.step * 0.5, 9)  # the next delivery's instant
            while True:
                with guard:
                    there = target in items
                if there:
                    break
                jitter()
                clock.idle()
            log.append((round(clock.now(), 9), len(items)))
        stop.set()

    producer, consumer = _threads(clock, produce, consume, producer=(0,))
    consumer.join(60)
    producer.join(60)
    assert not consumer.is_alive() and not producer.is_alive()
    return log


def test_a_waiter_sees_the_same_thing_at_the_same_instant_whatever_the_delays():
    """The consumer proceeds at exactly the instant the item it waits for is delivered, with the
    same number of items, whatever random delays the host adds: the nudge after each delivery
    (and the rule that a member nudged while it worked looks again before idling) leave no lost
    wake-up for time to slip through."""
    runs = [_producer_consumer(SteppedClock(step=0.1), random.Random(seed)) for seed in range(3)]
    assert runs[0] == runs[1] == runs[2]
    instants = [t for t, _ in runs[0]]
    assert np.allclose(np.diff(instants), 0.1)  # one delivery each, never one step late


def test_a_probe_holds_time_while_data_is_in_flight():
    """Time does not move while a probe says data is in flight (the pty's bytes on their way),
    even when every member waits; the idle members are woken to take it."""
    clock = SteppedClock(step=0.1)
    flight = threading.Event()
    flight.set()
    clock.watch(flight.is_set)
    woken = []

    def reader():
        clock.idle()
        woken.append(clock.now())
        flight.clear()  # took the data
        clock.sleep(1.0)

    (thread,) = _threads(clock, reader)
    thread.join(10)
    assert woken == [0.0] and clock.now() == pytest.approx(1.0)


def test_the_ledger_keeps_time_until_the_reader_took_what_was_sent():
    clock = SteppedClock()
    clock.taken("port", 100)  # the reader may take before the twin books it
    assert not clock.in_flight("port")
    clock.sent("port", 150)
    assert clock.in_flight("port")
    clock.taken("port", 50)
    assert not clock.in_flight("port")
    clock.sent("port", 10)
    clock.forget("port")  # reopened: pyserial flushed the input
    assert not clock.in_flight("port")


def test_an_unplugged_twin_leaves_no_bytes_in_flight():
    """Bytes a twin sent into a pty that nobody took are gone when the cable is pulled: time
    moves on (else it would wait for ever for a reader to take them, and a station would never
    see its IMU fall silent: a lost-device session on `station twin` hung so)."""
    from drivers.profile import SerialImuProfile
    from drivers.twins.serial import SerialTwin

    clock = SteppedClock(step=0.1)
    profile = SerialImuProfile.load("imu12_serial")
    channels = len(profile.imu.channels)
    twin = SerialTwin(profile, lambda t: np.zeros((len(t), channels), np.int64), clock=clock,
                      rate_hz=100.0)
    clock.watch(lambda: clock.in_flight(twin.port))  # a reader has the port open
    reached = []
    with twin:
        (station,) = _threads(clock, lambda: reached.append(clock.sleep(1.0) or clock.now()))
        deadline = time.monotonic() + 60  # a hang guard only
        while not clock.in_flight(twin.port) and time.monotonic() < deadline:
            time.sleep(0.01)
        assert clock.in_flight(twin.port) and clock.now() == pytest.approx(0.1)
        twin.unplug()
        station.join(60)
    assert reached == [pytest.approx(1.0)]


def test_real_time_clocks_keep_their_verbs():
    """The lockstep verbs are no-ops on real-time clocks (one code path for devices and
    recorder), and a scaled clock refuses a speed it cannot keep."""
    for clock in (WallClock(), ScaledClock(100.0)):
        clock.enlist()
        clock.nudge()
        clock.sent("x", 3)
        assert not clock.in_flight("x") and clock.realtime
        before = clock.now()
        clock.sleep(0.001 * clock.speed)
        assert clock.now() > before
    with pytest.raises(ValueError, match="positive and finite"):
        ScaledClock(float("inf"))
    assert not SteppedClock().realtime


SHORT = RotarySettings(static=2.0, revolutions=1)


def _record(path, imu: str) -> None:
    with VirtualBench(imu, seed=21, rate_hz=100.0, remount_time=1.0) as bench:
        record_rotary(bench, path, SHORT, suggested_axes(3))


def _spin(stop) -> None:
    while not stop.is_set():
        sum(range(10000))


def _contents(path) -> dict:
    out = {}
    with h5py.File(path, "r") as f:
        f.visititems(lambda name, obj: out.__setitem__(name, obj[()])
                     if isinstance(obj, h5py.Dataset) and not name.startswith("results")
                     else None)
    return out


def _same(a, b) -> bool:
    """Two datasets equal (NaN equal to NaN; bytes compared as bytes)."""
    if isinstance(a, bytes) or not hasattr(a, "dtype"):
        return a == b
    return np.array_equal(a, b, equal_nan=a.dtype.kind == "f")


@pytest.mark.parametrize("imu", ["serial", "can"])
def test_a_session_is_the_same_on_an_idle_and_on_a_busy_host(tmp_path, imu):
    """The same seed recorded twice in lockstep time, the second time beside two CPU hogs (with
    the suite's other worker: four busy processes on two cores): every sample, host time, table
    state and event is identical."""
    _record(tmp_path / "a.h5", imu)
    stop = multiprocessing.Event()
    hogs = [multiprocessing.Process(target=_spin, args=(stop,), daemon=True) for _ in range(2)]
    for hog in hogs:
        hog.start()
    try:
        _record(tmp_path / "b.h5", imu)
    finally:
        stop.set()
        for hog in hogs:
            hog.join(5)
    a, b = _contents(tmp_path / "a.h5"), _contents(tmp_path / "b.h5")
    assert sorted(a) == sorted(b)
    assert len(a["streams/imu/seq"]) > 2000
    for name in a:
        assert _same(a[name], b[name]), name


def test_a_station_in_another_process_keeps_lockstep_over_the_socket():
    """`station record` in another process than `station twin`: a `RemoteClock` on the served
    clock's socket. A producer on the served clock, a consumer on the remote one: the consumer
    sees each delivery at its instant, the same with random delays, and time waits for the bytes
    the ledger says are on their way to the remote reader."""
    from drivers.clock_link import ClockServer, RemoteClock

    def run(seed):
        served = SteppedClock(step=0.1)
        server = ClockServer(served)
        remote = RemoteClock(server.path)  # not `connect`: the socket, as another process
        try:
            delays = random.Random(seed)
            items, log, stop = [], [], threading.Event()

            def produce():
                while not stop.is_set():
                    served.pace(stop)
                    time.sleep(delays.random() * 0.002)
                    items.append(round(served.now(), 9))
                    served.nudge()

            def consume():
                for _ in range(15):
                    remote.sleep(0.05)
                    target = round(remote.now() + 0.05, 9)
                    while target not in items:
                        time.sleep(delays.random() * 0.002)
                        remote.idle()
                    log.append((round(remote.now(), 9), len(items)))
                stop.set()

            (producer,) = _threads(served, produce, producer=(0,))
            (consumer,) = _threads(remote, consume)
            consumer.join(60)
            producer.join(60)
            assert not consumer.is_alive()
            return log
        finally:
            remote.close()
            server.close()

    runs = [run(seed) for seed in range(2)]
    assert runs[0] == runs[1]
    assert np.allclose(np.diff([t for t, _ in runs[0]]), 0.1)


def test_the_served_clock_waits_for_bytes_the_remote_reader_has_not_taken():
    from drivers.clock_link import ClockServer, RemoteClock

    served = SteppedClock(step=0.1)
    server = ClockServer(served)
    remote = RemoteClock(server.path)
    try:
        remote.forget("port")  # the remote reader opened the port
        remote.advance_to(0.0)  # answered: the served clock has booked the forget
        served.sent("port", 58)
        seen = []

        def reader():
            while not remote.in_flight("port"):  # woken until told bytes are on their way
                remote.idle()
            seen.append(remote.now())
            remote.taken("port", 58)
            remote.sleep(1.0)
            seen.append(remote.now())

        (thread,) = _threads(remote, reader)
        thread.join(20)
        assert seen == [0.0, pytest.approx(1.0)]
    finally:
        remote.close()
        server.close()


def test_station_twin_and_station_record_in_two_processes_record_the_same_session(tmp_path):
    """`station twin` (lockstep time, the default for a rotary bench) and `station record` in
    two processes share the twin's clock over its socket: the same seed recorded twice gives the
    same samples, host times, table states and events, with no keyboard and no wall clock."""
    import subprocess

    from twinproc import STATION, TwinProcess

    def session(name):
        profile, path = tmp_path / f"{name}.toml", tmp_path / f"{name}.h5"
        with TwinProcess("--positions", "6", "--seed", "3", "--rate-hz", "100",
                         "--profile-out", str(profile), "--lifetime", "600") as twin:
            assert "lockstep" in twin.started and "clock_speed" not in twin.started
            rec = subprocess.run([*STATION, "record", "--profile", str(profile), "--out",
                                  str(path), "--json"], stdin=subprocess.DEVNULL, text=True,
                                 capture_output=True, timeout=600, check=False)
            assert rec.returncode == 0, rec.stderr
        return _contents(path)

    a, b = session("a"), session("b")
    assert sorted(a) == sorted(b) and len(a["streams/imu/seq"]) > 3000
    for name in a:
        if name != "metadata":  # it names each twin's ports
            assert _same(a[name], b[name]), name


def _lock_is_free(clock) -> bool:
    """Can another thread take the clock's lock (within a hang guard of 5 wall s)?"""

    def take():
        with clock._cond:
            pass

    return ends(take, 5)


def _interrupted_wait(k: int, remote: bool) -> str | None:
    """A station's main thread and a reader on the clock (over the socket: a `RemoteClock`), a
    Ctrl-C at the k-th place of the main thread's two sleeps (`signal_places.interrupted_at`),
    checked as below; where it landed (None: the sleeps ended first)."""
    from drivers.clock_link import ClockServer, RemoteClock

    served = SteppedClock(step=0.1, backstop=0.005)
    server = ClockServer(served) if remote else None
    clock = RemoteClock(server.path) if remote else served
    clock.backstop = 0.005
    stop = threading.Event()

    def reader():  # the recorder's, and a twin's streamer that sleeps
        while not stop.is_set():
            clock.idle(stop=stop)
            clock.sleep(0.1, stop)

    try:
        clock.enlist()
        (member,) = _threads(clock, reader)
        landed = interrupted_at(k, lambda: [clock.sleep(0.25) for _ in range(2)], CLOCK_CODE)
        assert _lock_is_free(clock), f"the clock's lock stayed taken after a Ctrl-C at {landed}"
        if landed:
            clock.advance_to(0.0)  # over the socket: once the served clock read every line
            held = served.now()
            time.sleep(0.03)  # the reader looks six times meanwhile
            assert served.now() == held, f"time moved while a Ctrl-C at {landed} was handled"
        stop.set()  # as `Recorder.stop` ends its reader
        clock.nudge()
        member.join(5)
        assert member not in threading.enumerate(), (  # not `is_alive`: it can lie (_ended)
            f"the reader never ended after a Ctrl-C at {landed}")
        clock.leave()
        return landed
    finally:
        if remote:
            clock.close()
            server.close()


@pytest.mark.parametrize("remote", [False, True], ids=["in-process", "over the socket"])
def test_a_ctrl_c_at_any_bytecode_of_a_wait_leaves_the_clock_working(remote):
    """A Ctrl-C or `kill` lands between any two bytecodes of the station's main thread, also inside
    a wait on the clock. Wherever it lands: the lock is free, time stands still while the
    interrupted thread handles it (it works, it does not wait), and the recorder's reader ends
    when told (a `station record` killed at a position's start once hung there: the clock's lock
    stayed taken by `Condition.__enter__`)."""
    k = 1
    while _interrupted_wait(k, remote):
        k += 1
    assert k > 30  # the sweep went through the waits' code


def _interrupted_is_alive(k: int) -> str | None:
    """A thread sleeping until 1.0 on the clock, a Ctrl-C at the k-th place of its `is_alive()`
    in the main thread, which then sleeps until 0.5 and leaves; where it landed (None: not at
    all), after checking the sleeper woke at 1.0."""
    clock = SteppedClock(backstop=0.005)
    woke, done = [], threading.Event()

    def sleeper():
        clock.sleep(1.0)
        woke.append(clock.now())
        done.set()

    clock.enlist()
    (thread,) = _threads(clock, sleeper)
    landed = interrupted_at(k, thread.is_alive, CLOCK_CODE)
    clock.sleep(0.5)
    clock.leave()
    done.wait(5)  # not `join`: it may no longer wait for the thread
    assert woke == [1.0], f"a Ctrl-C at {landed} woke the sleeper at {woke}"
    return landed


def test_a_ctrl_c_inside_is_alive_leaves_a_live_member_on_the_clock():
    """In Python 3.11 a KeyboardInterrupt landing inside `Thread.is_alive()` can mark the live
    thread stopped (bpo-45274's repair releases the thread's own lock). The clock must still count
    that thread: it sleeps on until its instant, not woken as if it had ended."""
    k = 1
    while _interrupted_is_alive(k):
        k += 1
    assert k > 3
