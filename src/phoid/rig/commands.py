"""The rig's command-line commands (``phoid virtual-rig``, ``phoid run``), registered in cli.py.

Errors a user can cause print one line ``phoid: error: …`` and exit with status 2.
"""

from __future__ import annotations

import re
import sys
import threading
import time
from pathlib import Path
from typing import Annotated, NoReturn

import typer

from phoid._output import echo_text, exit_with_error
from phoid._progress import task

__all__ = ["parse_listen", "run", "serve_until_stopped", "virtual_rig"]


def _fail(message: str) -> NoReturn:
    exit_with_error(message)


# the names VirtualRig's and Plant's messages use, and the options they come from
_RIG_OPTIONS = {"force_noise": "--force-noise", "offset_force": "--offset-force",
                "idle_timeout": "--idle-timeout", "max_session": "--max-session",
                "max_samples": "--max-samples", "max_rate": "--max-rate", "noise": "--noise",
                "quantum": "--quantum",
                "`offset`": "--offset-force", "`fc`": "--fc", "`m`": "--m", "`c`": "--c",
                "`k`": "--k", "`max_rate`": "--max-rate", "seed": "--seed"}


def _name_options(message: str) -> str:
    """A VirtualRig or Plant message in the command's words: ``max_rate`` or `` `m` `` →
    ``--max-rate``, ``--m`` (the user typed options, not keyword arguments).

    Every quoted name (`` `m` ``) is replaced; without one, the first bare name is (a bare
    word could also be plain text further on)."""
    quoted = 0
    for name, flag in _RIG_OPTIONS.items():
        if name.startswith("`"):
            message, hits = re.subn(re.escape(name), flag, message)
            quoted += hits
    if quoted:
        return message
    for name, flag in _RIG_OPTIONS.items():
        message, hits = re.subn(rf"(?<![\w-]){name}(?![\w-])", flag, message, count=1)
        if hits:
            return message
    return message


def parse_listen(listen: str) -> tuple[str, int]:
    """--listen's ``HOST:PORT`` (or ``tcp://HOST:PORT``; port 0: a free one) → (host, port).

    Raises
    ------
    ValueError
        One line naming --listen.
    """
    from phoid.rig.host import parse_port

    text = listen[6:] if listen.startswith("tcp://") else listen
    host, sep, num = text.rpartition(":")
    shown = listen if len(listen) <= 200 else listen[:200] + "..."
    if (not sep or not host or "://" in text or not re.fullmatch(r"[0-9]{1,5}", num)
            or int(num) > 65535):
        raise ValueError(f"--listen must be HOST:PORT (port 1 to 65535, or 0 for a free one); "
                         f"got {shown!r}")
    try:
        host, _ = parse_port(f"{host}:1")  # the host's checks (a name or an IP address)
    except ValueError as exc:
        # the host's checks name --port and quote the address they were given (HOST:1):
        # said of --listen, quoting what the user gave
        why = re.sub(r"; got .*$", "", re.sub(r"^--port\b", "--listen", str(exc)))
        raise ValueError(f"{why}; got {shown!r}") from None
    return host, int(num)


def virtual_rig(
    m: Annotated[float, typer.Option("--m", help="Mass, kg.")],
    c: Annotated[float, typer.Option("--c", help="Viscous damping, N s/m.")],
    k: Annotated[float, typer.Option("--k", help="Stiffness, N/m.")],
    fc: Annotated[float, typer.Option("--fc", help="Coulomb friction force, N.")] = 0.0,
    offset_force: Annotated[float, typer.Option(
        "--offset-force", help="Constant offset force, N.")] = 0.0,
    noise: Annotated[float, typer.Option(help="Position sensor noise sd, m.")] = 0.0,
    quantum: Annotated[float, typer.Option(
        help="The encoder's count, m: the position read and streamed is rounded to a multiple "
             "of it (0: none).")] = 0.0,
    seed: Annotated[int | None, typer.Option(help="Seed of the noise.")] = None,
    noise_outside_loop: Annotated[bool, typer.Option(
        "--noise-outside-loop", help="Add the noise to the streamed x only; the controller "
                                     "reads the exact position (phoid simulate's model).")
    ] = False,
    listen: Annotated[str, typer.Option(
        help="Address to serve on, HOST:PORT.")] = "127.0.0.1:8765",
    realtime: Annotated[bool, typer.Option(
        "--realtime", help="Pace the samples to the wall clock.")] = False,
    build: Annotated[Path | None, typer.Option(
        help="Folder to build the C controller in [a temporary folder].")] = None,
    max_rate: Annotated[float, typer.Option(
        "--max-rate", help="Fastest sample rate the rig accepts, Hz.")] = 20000.0,
    force_noise: Annotated[float | None, typer.Option(
        "--force-noise", help="Report a measured force (the force applied plus white noise of "
                              "this sd, N) in each sample; off by default.")] = None,
    idle_timeout: Annotated[float, typer.Option(
        "--idle-timeout", help="End a session whose host sends nothing for this long, s "
                               "(outside a run).")] = 30.0,
    max_session: Annotated[float, typer.Option(
        "--max-session", help="The longest a session may hold the rig, s.")] = 3600.0,
    max_samples: Annotated[int, typer.Option(
        "--max-samples", help="The most samples one run may take (hold + run + 1).")
    ] = 2_000_000,
) -> None:
    """Serve a simulated rig: the compiled C controller against phoid's exact plant.

    Speaks the rig protocol PHOID-RIG 1 (docs/rig-protocol.md; its binary framing too, when
    the host offers FRAMING cobs) on --listen, one host at a time
    (another is refused at once: ERROR busy), until interrupted (Ctrl-C or SIGTERM: it then
    stops serving and removes its temporary build folder). A host silent for --idle-timeout s
    or a session older than --max-session s is closed with an ERROR. Needs a C compiler.
    """

    from phoid.dynamics.plant import Plant
    from phoid.rig.virtual import VirtualRig

    try:
        host, port = parse_listen(listen)
        rig = VirtualRig(Plant(m=m, c=c, k=k, fc=fc), offset_force=offset_force, noise=noise,
                         quantum=quantum, seed=seed, realtime=realtime, build=build,
                         max_rate=max_rate,
                         noise_in_loop=not noise_outside_loop, force_noise=force_noise,
                         idle_timeout=idle_timeout, max_session=max_session,
                         max_samples=max_samples)
    except (ValueError, OSError) as exc:
        _fail(_name_options(str(exc)))
    serve_until_stopped(rig, host, port, f"virtual rig (m={m:g} kg, c={c:g} N s/m, "
                                         f"k={k:g} N/m, fc={fc:g} N)")


def serve_until_stopped(server, host: str, port: int, what: str) -> None:
    """Listen on ``host:port``, say so in one line, and serve until Ctrl-C or SIGTERM.

    Parameters
    ----------
    server : VirtualRig or VirtualPlant
        What serves: its ``listen(host, port)`` gives the address bound (a ValueError: one
        line, exit status 2) and its ``close()`` runs however the command ends.
    host, port : str, int
        The address (port 0: a free one).
    what : str
        What is listening, for the line.
    """
    import signal

    try:
        try:
            host, port = server.listen(host, port)
        except ValueError as exc:
            _fail(str(exc))
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))  # runs the `finally` below
        typer.echo(f"{what} listening on tcp://{host}:{port}; Ctrl-C stops it", err=True)
        while True:
            time.sleep(3600)
    finally:
        server.close()


class _Terminated(KeyboardInterrupt):
    """SIGTERM on `phoid run`: handled as Ctrl-C is (the run in progress recorded, ABORT sent)."""


def _terminate(signum: int, frame: object) -> None:
    raise _Terminated("SIGTERM")


def run(
    plan: Annotated[Path, typer.Argument(help="The plan: a folder (or experiment.toml) "
                                              "written by `phoid design --out`.")],
    port: Annotated[str, typer.Option(
        help="The rig: tcp://HOST:PORT or serial:///dev/DEVICE[?baud=N] (POSIX; 115200).")],
    out: Annotated[str | None, typer.Option(
        "--out", "-o", help="The set's folder [PLAN-run beside the plan].")] = None,
    resume: Annotated[bool, typer.Option(
        "--resume", help="Continue a set begun before: run the runs not done.")] = False,
    pmax: Annotated[float | None, typer.Option(help="The rig's limit on |P|, N/m.")] = None,
    dmax: Annotated[float | None, typer.Option(help="The rig's limit on |D|, N s/m.")] = None,
    hold_p: Annotated[float | None, typer.Option(
        "--hold-p", help="Hold loop P, N/m [3 k of the plan's prior].")] = None,
    hold_d: Annotated[float | None, typer.Option(
        "--hold-d", help="Hold loop D, N s/m (default: about critical damping).")] = None,
    hold: Annotated[float | None, typer.Option(
        help="Hold time before the release, s [7 time constants of the hold].")] = None,
    x_limit: Annotated[float | None, typer.Option(
        "--x-limit", help="Position limit |x|, m [3 x the release amplitude].")] = None,
    u_max: Annotated[float | None, typer.Option(
        "--u-max", help="Command limit, N (default: none).")] = None,
    timeout: Annotated[float, typer.Option(
        help="Seconds to wait for the rig (connection, each line, each send; at most a day); "
             "each run also ends within --timeout + (its samples) x (2T + 0.1 ms).")] = 10.0,
    framing: Annotated[str, typer.Option(
        help="How the samples travel: 'text' (PHOID-RIG 1 lines, every rig), 'auto' (offer "
             "the binary COBS frames a microcontroller rig speaks, keep text when the rig "
             "refuses) or 'binary' (insist: a rig that refuses is an error). "
             "docs/rig-protocol.md.")] = "text",
) -> None:
    """Run a designed plan on a rig and write the phoid/1 set as the samples arrive.

    Reads the plan, refuses gains beyond --pmax/--dmax before anything moves, then for each
    run configures the rig, starts it and streams its samples into the run's CSV. The manifest
    is rewritten after every run; a run the controller aborts is kept (runNN.aborted.csv) and
    marked, a run cut off by the link or not as configured (runNN.incomplete.csv) is run again
    by --resume. Every option is checked, and no file in --out is replaced, before anything
    moves (docs/rig-protocol.md, "Limits of the host"). Exit status 0 when every run
    completed, 1 when some did not, 2 on bad input; Ctrl-C (130) and SIGTERM (143) stop it
    after the run in progress is recorded (incomplete) and the rig is sent ABORT.
    """
    import os
    import signal

    from phoid.rig.host import RigError, run_plan

    if out is not None and not out.strip():
        _fail("--out must name a folder; got an empty name")
    if out is None:  # beside the plan: `phoid run .` inside the plan's folder too
        where = Path(os.path.abspath(plan))
        base = where.parent if where.suffix == ".toml" else where
        out_path = base.parent / f"{base.name}-run"
    else:
        out_path = Path(out)
    main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _terminate) if main else None
    try:
        # the bar of phoid._progress: drawn only where the CLI switched progress on
        with task("run", total=None) as advance:

            def progress(i: int, n: int, total: int) -> None:
                advance(0, description=f"run {i}: samples", completed=n, total=total)

            result = run_plan(plan, port, out_path, resume=resume, timeout=timeout,
                              progress=progress, framing=framing, pmax=pmax, dmax=dmax,
                              hold_p=hold_p, hold_d=hold_d, hold=hold, x_limit=x_limit,
                              u_max=u_max)
    except (RigError, ValueError, OSError) as exc:
        _fail(str(exc))
    except KeyboardInterrupt as exc:  # Ctrl-C (130) or SIGTERM (143): one line, both
        term = isinstance(exc, _Terminated)
        manifest = out_path / "experiment.toml"
        kept = (f"the runs recorded are in {manifest} (pass --resume to run the rest)"
                if manifest.is_file() else f"nothing was recorded in {out_path}")
        typer.echo(f"phoid: stopped by {'SIGTERM' if term else 'SIGINT (Ctrl-C)'}; {kept}",
                   err=True)
        raise typer.Exit(143 if term else 130) from None
    finally:
        if main:
            signal.signal(signal.SIGTERM, signal.SIG_DFL if previous is None else previous)
    for msg in result.messages:
        echo_text(f"phoid: {msg}", err=True, wrap=False)
    done = sum(s == "complete" for s in result.statuses)
    echo_text(f"{done} of {len(result.statuses)} runs complete; set written to "
              f"{result.manifest}", wrap=False)
    if not result.complete:
        typer.echo("phoid: the plan is not complete (pass --resume to run the rest)", err=True)
        raise typer.Exit(1)
