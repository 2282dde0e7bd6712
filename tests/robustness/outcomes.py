"""How a robustness case runs a `seuwgpu` command and what its outcome must be.

A bad input must end in a clear error: exit status 2 (3 for `view` without a display) and one
line saying `error:`, no traceback. A valid input must end with exit status 0 and a result that
passes its check. Anything else (a traceback, another status, exit 0 where an error was due, a
result that fails its check) fails the test.
"""

from __future__ import annotations

import contextlib
import io
import os
import traceback
import warnings
from dataclasses import dataclass

from seuwgpu.apps.cli import main

TOP = {"views": "1", "size": '"16x16"', "batch": "4"}
SCENE = 'scene = "spheres"\nn = 60\n'
SINGLE = {"fields": '["opacity"]', "bits": "[30]", "samples": "2", "defenses": '["none"]'}


def table(name: str, base: dict, **over) -> str:
    """A TOML table from base values with some replaced (None: left out)."""
    vals = {**base, **over}
    return f"[{name}]\n" + "".join(f"{k} = {v}\n" for k, v in vals.items() if v is not None)


def spec_text(top=None, scene=None, single=None, extra=""):
    """A tiny valid spec, with top-level values replaced (`top`: {key: TOML value}), another scene
    entry, another [single] table ("" for none) and extra tables."""
    head = "".join(f"{k} = {v}\n" for k, v in {**TOP, **(top or {})}.items() if v is not None)
    return (
        head
        + "[[scenes]]\n"
        + (SCENE if scene is None else scene)
        + (table("single", SINGLE) if single is None else single)
        + extra
    )


@dataclass
class Outcome:
    rc: int | None
    out: str
    err: str
    traceback: bool = False
    timeout: bool = False

    @property
    def last(self) -> str:
        return self.err.strip().splitlines()[-1] if self.err.strip() else ""


def run_cli(argv, env=None) -> Outcome:
    """`seuwgpu ARGV` in this process through main(argv), with `env` set for its duration."""
    out, err = io.StringIO(), io.StringIO()
    env = env or {}
    old_env = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    rc, tb = None, False
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), warnings.catch_warnings():
            warnings.simplefilter("default")
            try:
                rc = main([str(a) for a in argv])
            except SystemExit as e:  # argparse; any other code as the interpreter reads it
                rc = e.code if isinstance(e.code, int) else 0 if e.code is None else 1
            except Exception:  # a traceback is what these tests look for: kept to be shown
                tb = True
                err.write(traceback.format_exc())
    finally:
        for k, v in old_env.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    return Outcome(rc, out.getvalue(), err.getvalue(), tb)


def assert_clear_error(o: Outcome, argv=(), says: str = ""):
    """Exit status 2 (3 for `view`) with one line saying `error:` (and `says`) and no traceback."""
    assert not o.traceback, f"traceback:\n{o.err}"
    assert not o.timeout, "timed out"
    assert o.rc != 0, f"silent wrong: exit 0 where an error was due; stdout: {o.out[-300:]}"
    assert o.rc in (2, 3), f"crash: exit status {o.rc}: {o.last}"
    errors = [line for line in o.err.splitlines() if "error:" in line or "seuwgpu view:" in line]
    is_view = o.rc == 3 and "view" in [str(a) for a in argv][:1]
    assert len(errors) == 1 or is_view, f"exit {o.rc} without a one-line error: {o.err[-500:]}"
    assert not says or any(says in line for line in errors), f"the error does not say '{says}': {o.last}"


def assert_correct(o: Outcome, check=None, stderr_has: str = ""):
    """Exit status 0 and the result passes `check(stdout)` (and stderr holds `stderr_has`)."""
    assert not o.traceback, f"traceback:\n{o.err}"
    assert not o.timeout, "timed out"
    assert o.rc == 0, f"refused or crashed: exit status {o.rc}: {o.err[-500:]}"
    if check is not None:
        check(o.out)
    if stderr_has:
        assert stderr_has in o.err, f"no '{stderr_has}' on stderr: {o.last}"


def expect_outcome(argv, expect: str, check=None, env=None, stderr_has: str = ""):
    """Run argv in this process and assert the outcome `expect` ("error" or "ok"); `stderr_has`:
    what stderr must hold, for an error its error line (where another error could stand in for
    the one due)."""
    o = run_cli(argv, env)
    if expect == "error":
        assert_clear_error(o, argv, stderr_has)
    else:
        assert_correct(o, check, stderr_has)
    return o
