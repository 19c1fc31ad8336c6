"""``phoid virtual-plant``: the exact plant for a firmware in the loop (registered in cli.py).

Errors a user can cause print one line ``phoid: error: …`` and exit with status 2.
"""

from __future__ import annotations

import re
from typing import Annotated, NoReturn

import typer

from phoid._output import exit_with_error
from phoid.rig.commands import parse_listen, serve_until_stopped

__all__ = ["virtual_plant"]

# the names PlantModel's and Plant's messages use, and the options they come from
_OPTIONS = {"`m`": "--m", "`c`": "--c", "`k`": "--k", "`fc`": "--fc",
            "`offset`": "--offset-force", "noise": "--noise", "quantum": "--quantum",
            "seed": "--seed"}


def _fail(message: str) -> NoReturn:
    exit_with_error(message)


def _in_option_words(message: str) -> str:
    """A PlantModel or Plant message with its parameter names as the options (``--m``)."""
    for name, flag in _OPTIONS.items():
        message = re.sub(rf"(?<![\w`-]){re.escape(name)}(?![\w`-])", flag, message)
    return message


def virtual_plant(
    m: Annotated[float, typer.Option("--m", help="Mass, kg.")],
    c: Annotated[float, typer.Option("--c", help="Viscous damping, N s/m.")],
    k: Annotated[float, typer.Option("--k", help="Stiffness, N/m.")],
    fc: Annotated[float, typer.Option("--fc", help="Coulomb friction force, N.")] = 0.0,
    offset_force: Annotated[float, typer.Option(
        "--offset-force", help="Constant offset force, N.")] = 0.0,
    noise: Annotated[float, typer.Option(help="Position sensor noise sd, m.")] = 0.0,
    quantum: Annotated[float, typer.Option(
        help="The encoder's count, m: the position read is rounded to a multiple of it "
             "(0: none).")] = 0.0,
    seed: Annotated[int | None, typer.Option(help="Seed of the noise.")] = None,
    listen: Annotated[str, typer.Option(
        help="Address to serve the MCU's plant link on, HOST:PORT (0: a free port).")
    ] = "127.0.0.1:8766",
) -> None:
    """Serve phoid's exact plant to a firmware in the loop (QEMU's second serial line).

    The firmware (src/phoid/rig/c/firmware, board mps2_hil) reads one position per sample
    from this plant and sends back the command it applies; the plant moves one sample period
    under it exactly (zero-order hold) and sends the next position, in lockstep. Start it
    first, then QEMU with -serial tcp:HOST:PORT for the board's UART1, then `phoid run
    --port` on UART0. Runs until interrupted (Ctrl-C or SIGTERM).
    """
    from phoid.dynamics.plant import Plant
    from phoid.rig.plant import PlantModel, VirtualPlant

    try:
        host, port = parse_listen(listen)
        model = PlantModel(Plant(m=m, c=c, k=k, fc=fc), offset_force=offset_force,
                           noise=noise, quantum=quantum, seed=seed)
        server = VirtualPlant(model)
    except (ValueError, OSError) as exc:
        _fail(_in_option_words(str(exc)))
    serve_until_stopped(server, host, port, f"virtual plant (m={m:g} kg, c={c:g} N s/m, "
                                            f"k={k:g} N/m, fc={fc:g} N)")
