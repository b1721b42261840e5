"""A Ctrl-C at every place it can land: `interrupted_at(k, call, code)` raises KeyboardInterrupt
at the k-th place of `call()` where CPython 3.11 runs a signal handler, in the code of the files
(or under the directories) `code`. A test sweeps k = 1, 2, ... until the call ends first, and
checks after each what must hold after a Ctrl-C anywhere (tests/test_lockstep.py: the clock;
tests/test_table_modbus.py: the table; test_cli_logging.py: the log; test_session_kill.py: the
session file; test_wake.py: `station twin`'s wait; test_abort_shield.py, with a real signal
sent instead: a second Ctrl-C during an abort). `ends(call, guard)` asks whether a call
another thread makes still returns (a lock left taken blocks it for ever)."""

import dis
import os
import sys
import threading

BREAKERS = {"CALL", "CALL_FUNCTION_EX", "JUMP_BACKWARD"}
"""Bytecodes after which CPython 3.11 checks its eval breaker (runs pending signal handlers)."""


def interrupted_at(k: int, call, code: tuple, send: int | None = None,
                   armed=None) -> str | None:
    """Run `call()` in this thread with a KeyboardInterrupt raised at the k-th place a Ctrl-C's
    handler can run in `code` (file paths or directory prefixes): when a frame starts, after a
    call returns and at a loop's jump back, never at a NOP (which no `with` or `try` covers) nor
    between a PRECALL and its CALL. The handler's exception belongs to the call (or the jump):
    raised at the next bytecode instead, it stands for it where both are covered by the same
    `with` or `try` (or by none). With `send` (a signal number) the signal is sent to this
    process there instead, its installed handler deciding what happens; with `armed`, places
    count only once `armed()` is true. Where it was raised or sent ("_wait line 261 (place
    7)"), or None (the call ended before its k-th place)."""
    codes, last, count, where = {}, {}, 0, []

    def handler(code, offset):
        """The target of the `with` or `try` that covers `offset`, None outside any."""
        return next((e.target for e in codes[code][1] if e.start <= offset < e.end), None)

    def local(frame, event, arg):
        nonlocal count
        if event != "opcode":
            return local
        code, now = frame.f_code, frame.f_lasti
        if code not in codes:
            bytecode = dis.Bytecode(code)
            codes[code] = ({i.offset: i.opname for i in bytecode}, bytecode.exception_entries)
        ops = codes[code][0]
        before = last.get(frame, 0)  # a frame's first: its RESUME
        last[frame] = now
        called = (ops.get(before) in BREAKERS or before == 0
                  or ops.get(before) == "PRECALL" and ops.get(now) != "CALL")
        if called and handler(code, before) == handler(code, now) and (armed is None or armed()):
            count += 1
            if count == k:
                where.append(f"{code.co_name} line {frame.f_lineno} (place {k})")
                if send is None:
                    raise KeyboardInterrupt(where[0])
                os.kill(os.getpid(), send)  # its handler runs here, at the next bytecode
        return local

    def tracer(frame, event, arg):
        if not frame.f_code.co_filename.startswith(code):
            return None
        frame.f_trace_opcodes = True
        return local

    sys.settrace(tracer)
    try:
        call()
    except KeyboardInterrupt:
        pass
    except RuntimeError as exc:  # between Condition.wait's release and its `try`
        assert any(words in str(exc) for words in ("un-acquired lock", "release unlocked lock"))
        assert isinstance(exc.__context__, KeyboardInterrupt)
    finally:
        sys.settrace(None)
    return where[0] if where else None


def ends(call, guard: float) -> bool:
    """Does `call()`, run in another thread, return within `guard` wall seconds (a hang guard:
    a lock a Ctrl-C left taken blocks it for ever)? One that raises does not."""
    done = []

    def run():
        call()
        done.append(True)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(guard)
    return done == [True]
