"""Shared helpers of the microcontroller tests (tests/test_mcu_*.py).

The tests build phoid's rig controller (src/phoid/rig/c) for real microcontrollers with
Debian's cross toolchains and run it in emulators. Each tool is found on PATH; a test that
needs a missing one is skipped with a reason naming the Debian package that provides it, so
a clone without them still passes.

Targets (``TARGETS``): Cortex-M0, M3, M4F (single-precision FPU; a ``float`` and a ``double``
build), M7 (double-precision FPU) and AVR atmega2560 (whose ``double`` has 32 bits). Every
build uses ``STRICT_FLAGS`` and ``OPT`` (-O2: a control loop on an MCU is built for speed;
the build gate also compiles at -Os for the warnings that depend on the optimiser).
"""

from __future__ import annotations

import re
import shutil
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CONTROLLER_DIR = ROOT / "src" / "phoid" / "rig" / "c"
FIRMWARE_DIR = CONTROLLER_DIR / "firmware"
MCU_DIR = Path(__file__).resolve().parent / "mcu"

STRICT_FLAGS = (
    "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-Wfloat-equal",
    "-ffp-contract=off",
)
OPT = "-O2"
ALLOWED_LIBC = frozenset({"memcpy", "memset"})
TOOL_TIMEOUT = 120  # s: one compile, link or emulator run (each takes well under 2 s here)

ARM_PACKAGE = "gcc-arm-none-eabi"
AVR_PACKAGE = "gcc-avr"
PACKAGES = {
    "arm-none-eabi-gcc": ARM_PACKAGE,
    "arm-none-eabi-nm": "binutils-arm-none-eabi (with gcc-arm-none-eabi)",
    "arm-none-eabi-size": "binutils-arm-none-eabi (with gcc-arm-none-eabi)",
    "arm-none-eabi-objdump": "binutils-arm-none-eabi (with gcc-arm-none-eabi)",
    "qemu-system-arm": "qemu-system-arm",
    "avr-gcc": AVR_PACKAGE,
    "avr-nm": "binutils-avr (with gcc-avr)",
    "avr-size": "binutils-avr (with gcc-avr)",
    "avr-objdump": "binutils-avr (with gcc-avr)",
    "simavr": "simavr",
    "make": "make",
}


@dataclass(frozen=True)
class Target:
    """One microcontroller build.

    Attributes
    ----------
    name : str
        The target's name in test ids and tables ("m4f-float").
    arch : str
        "arm" or "avr": the tool prefix (arm-none-eabi-, avr-).
    flags : tuple of str
        The CPU flags.
    real : str
        "double" or "float": ``PHOID_REAL`` of the build.
    machine : str or None
        The QEMU board that runs it (None: no QEMU board).
    """

    name: str
    arch: str
    flags: tuple[str, ...]
    real: str
    machine: str | None

    @property
    def prefix(self) -> str:
        """The binutils prefix ("arm-none-eabi-", "avr-")."""
        return "arm-none-eabi-" if self.arch == "arm" else "avr-"

    @property
    def defines(self) -> tuple[str, ...]:
        """The -D flags of the real type (none for the default double)."""
        return ("-DPHOID_REAL=float",) if self.real == "float" else ()


_M4F = ("-mcpu=cortex-m4", "-mthumb", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard")
TARGETS = {
    t.name: t
    for t in (
        Target("m0", "arm", ("-mcpu=cortex-m0", "-mthumb"), "double", "microbit"),
        Target("m3", "arm", ("-mcpu=cortex-m3", "-mthumb"), "double", "mps2-an385"),
        Target("m4f-float", "arm", _M4F, "float", "mps2-an386"),
        Target("m4f-double", "arm", _M4F, "double", "mps2-an386"),
        Target(
            "m7", "arm",
            ("-mcpu=cortex-m7", "-mthumb", "-mfpu=fpv5-d16", "-mfloat-abi=hard"),
            "double", "mps2-an500",
        ),
        Target("avr", "avr", ("-mmcu=atmega2560",), "double", None),
    )
}


def tool(name: str) -> str:
    """The path of a tool on PATH, or skip the test naming the Debian package to install.

    Parameters
    ----------
    name : str
        The program ("arm-none-eabi-gcc", "qemu-system-arm", "simavr", ...).

    Returns
    -------
    str
        Its absolute path.
    """
    path = shutil.which(name)
    if path is None:
        package = PACKAGES.get(name, name)
        pytest.skip(f"{name} not found on PATH: install Debian's {package}")
    return path


def need_toolchain(target: Target) -> None:
    """Skip unless the target's compiler and binutils are installed."""
    for name in ("gcc", "nm", "size"):
        tool(target.prefix + name)


def compiler_version(target: Target) -> str:
    """The version of a target's compiler: ``gcc -dumpfullversion`` ("12.2.1"), or
    ``-dumpversion`` from a GCC before 7, which has no -dumpfullversion (avr-gcc "5.4.0")."""
    need_toolchain(target)
    gcc = target.prefix + "gcc"
    proc = subprocess.run([gcc, "-dumpfullversion"], capture_output=True, text=True,
                          timeout=TOOL_TIMEOUT, check=False)
    if proc.returncode == 0 and proc.stdout.strip():
        return proc.stdout.strip()
    return run_tool([gcc, "-dumpversion"], "asking the compiler's version").strip()


def controller_has_real_type() -> bool:
    """Whether the controller's header has the compile-time real type (``phoid_real``)."""
    return "phoid_real" in (CONTROLLER_DIR / "phoid_ctrl.h").read_text(encoding="utf-8")


def need_real(target: Target) -> None:
    """Skip a float build of a controller that has no ``PHOID_REAL`` yet."""
    if target.real == "float" and not controller_has_real_type():
        pytest.skip("the controller has no compile-time real type (PHOID_REAL) to build float")


def run_tool(
    args: list[str], what: str, timeout: float = TOOL_TIMEOUT, *, stderr: bool = False
) -> str:
    """Run a tool, returning its stdout; fail the test with its stderr when it fails.

    Parameters
    ----------
    args : list of str
        The command line.
    what : str
        What it does, for the failure message.
    timeout : float
        Seconds before it is killed (then the test fails).
    stderr : bool
        True: return the standard error after the standard output (simavr writes the
        firmware's USART there).

    Returns
    -------
    str
        The tool's standard output.
    """
    try:
        proc = subprocess.run(args, capture_output=True, text=True, timeout=timeout, check=False)
    except subprocess.TimeoutExpired:
        pytest.fail(f"{what}: no exit after {timeout:.0f} s: {' '.join(args)}", pytrace=False)
    if proc.returncode != 0:
        pytest.fail(
            f"{what} failed (exit {proc.returncode}): {' '.join(args)}\n{proc.stdout}{proc.stderr}",
            pytrace=False,
        )
    return proc.stdout + proc.stderr if stderr else proc.stdout


def compile_sources(
    target: Target,
    sources: list[Path],
    out_dir: Path,
    *,
    opt: str = OPT,
    strict: bool = True,
    extra: tuple[str, ...] = (),
) -> list[Path]:
    """Compile sources for a target into objects in out_dir (one object per source).

    Parameters
    ----------
    target : Target
        The build.
    sources : list of Path
        The C files.
    out_dir : Path
        Where the objects go (created).
    opt : str
        The optimisation flag.
    strict : bool
        True: ``STRICT_FLAGS`` (warnings are errors); False: only -std=c99 and
        -ffp-contract=off (for the tests' own start-up files, which take liberties).
    extra : tuple of str
        More flags (-I, -D).

    Returns
    -------
    list of Path
        The objects, in the order of the sources.
    """
    need_toolchain(target)
    out_dir.mkdir(parents=True, exist_ok=True)
    flags = STRICT_FLAGS if strict else ("-std=c99", "-ffp-contract=off")
    objects = []
    for src in sources:
        obj = out_dir / (src.stem + ".o")
        run_tool(
            [
                target.prefix + "gcc", *target.flags, *flags, opt, *target.defines,
                f"-I{CONTROLLER_DIR}", f"-I{MCU_DIR}", *extra, "-c", str(src), "-o", str(obj),
            ],
            f"compiling {src.name} for {target.name}",
        )
        objects.append(obj)
    return objects


def runtime_libraries(target: Target) -> list[str]:
    """The compiler runtime a target links with: libgcc; on AVR also avr-libc's libm.a,
    where avr-gcc keeps its floating-point routines (__addsf3, __mulsf3, ...)."""
    libs = [run_tool([target.prefix + "gcc", *target.flags, "-print-libgcc-file-name"],
                     "finding libgcc").strip()]
    if target.arch == "avr":
        libm = run_tool([target.prefix + "gcc", *target.flags, "-print-file-name=libm.a"],
                        "finding avr-libc's libm.a").strip()
        libs.append(libm)
    return libs


def runtime_symbols(target: Target) -> frozenset[str]:
    """The symbols the compiler runtime defines (libgcc; on AVR also libm's ``__`` routines,
    its floating-point support, and none of its math functions)."""
    names: set[str] = set()
    for i, lib in enumerate(runtime_libraries(target)):
        out = run_tool([target.prefix + "nm", "--defined-only", "-g", lib], f"listing {lib}")
        for line in out.splitlines():
            parts = line.split()
            if len(parts) == 3 and (i == 0 or parts[2].startswith("__")):
                names.add(parts[2])
    return frozenset(names)


def undefined_symbols(target: Target, objects: list[Path]) -> set[str]:
    """The symbols the objects use and do not define among themselves (``nm -u``)."""
    used: set[str] = set()
    defined: set[str] = set()
    for obj in objects:
        for line in run_tool([target.prefix + "nm", "-u", str(obj)], "nm -u").splitlines():
            if line.strip():
                used.add(line.split()[-1])
        out = run_tool([target.prefix + "nm", "--defined-only", "-g", str(obj)], "nm")
        defined.update(line.split()[-1] for line in out.splitlines() if line.strip())
    return used - defined


def link(target: Target, objects: list[Path], elf: Path) -> Path:
    """Link objects with nothing but the compiler runtime (``-nostdlib -nostartfiles``; the
    start-up file provides memcpy and memset). ARM uses tests/mcu/cortexm.ld."""
    need_toolchain(target)
    args = [target.prefix + "gcc", *target.flags, "-nostdlib", "-nostartfiles"]
    if target.arch == "arm":
        args += ["-T", str(MCU_DIR / "cortexm.ld")]
    args += ["-o", str(elf), *map(str, objects)]
    args += ["-lgcc"] if target.arch == "arm" else ["-Wl,--start-group", "-lgcc", "-lm",
                                                      "-Wl,--end-group"]
    run_tool(args, f"linking {elf.name} for {target.name}")
    return elf


def elf_sizes(target: Target, elf: Path) -> tuple[int, int]:
    """(flash, ram) of a linked ELF in bytes: flash = text + data (the code, constants and
    the initial values of data), RAM = data + bss (the stack not counted)."""
    out = run_tool([target.prefix + "size", "-B", str(elf)], "size")
    text, data, bss = (int(v) for v in out.splitlines()[1].split()[:3])
    return text + data, data + bss


def symbol_address(target: Target, elf: Path, name: str) -> int:
    """The address of a symbol in an ELF (the Thumb bit cleared)."""
    for line in run_tool([target.prefix + "nm", str(elf)], "nm").splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[2] == name:
            return int(parts[0], 16) & ~1
    pytest.fail(f"{name} not in {elf.name}", pytrace=False)


def firmware_sources(name: str) -> list[Path]:
    """tests/mcu/<name>.c with its target-independent parts (the controller)."""
    return [MCU_DIR / f"{name}.c", CONTROLLER_DIR / "phoid_ctrl.c"]


def start_file(target: Target) -> Path:
    """The tests' start-up file of a target (vectors, .data/.bss, memcpy/memset, markers)."""
    return MCU_DIR / ("cortexm_start.c" if target.arch == "arm" else "avr_start.c")


_TRACE = re.compile(r"^Trace \d+: \S+ \[[0-9a-f]+/([0-9a-f]+)/")


TRACE_MAX_BYTES = 200_000_000  # a cost run logs ~3 MB; a firmware that hangs, ~80 MB/s


def qemu_trace(target: Target, elf: Path, log: Path, timeout: float = 30.0) -> None:
    """Run an ELF on the target's QEMU board, one instruction per translation block, logging
    every block executed (``-singlestep -d exec,nochain``: one log line per instruction). The
    firmware leaves through semihosting; a non-zero exit fails the test with its console, and
    so does a run past ``timeout`` seconds or a log past ``TRACE_MAX_BYTES`` (a firmware that
    does not finish: QEMU is killed before the log fills the disk)."""
    qemu = tool("qemu-system-arm")
    assert target.machine is not None
    args = [
        qemu, "-M", target.machine, "-nographic", "-monitor", "none", "-serial", "none",
        "-semihosting-config", "enable=on,target=native", "-singlestep",
        "-d", "exec,nochain", "-D", str(log), "-kernel", str(elf),
    ]
    what = f"running {elf.name} on QEMU {target.machine}"
    with subprocess.Popen(
        args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL
    ) as proc:
        start = time.monotonic()
        while proc.poll() is None:
            big = log.exists() and log.stat().st_size > TRACE_MAX_BYTES
            if big or time.monotonic() - start > timeout:
                proc.kill()
                proc.wait()
                log.unlink(missing_ok=True)
                pytest.fail(
                    f"{what}: no exit after {time.monotonic() - start:.0f} s"
                    f"{' and a trace over ' + str(TRACE_MAX_BYTES) + ' bytes' if big else ''}",
                    pytrace=False,
                )
            time.sleep(0.02)
        console = proc.stdout.read().decode(errors="replace") if proc.stdout else ""
    if proc.returncode != 0:
        pytest.fail(f"{what} failed (exit {proc.returncode}): {console[-2000:]}",
                    pytrace=False)


def marked_counts(begin: int, end: int, log: Path) -> list[int]:
    """The instructions executed from each entry of the begin marker up to the next entry of
    the end marker (the begin marker's own instructions included), in order."""
    counts: list[int] = []
    current: int | None = None
    with log.open(encoding="utf-8", errors="replace") as fh:
        for line in fh:
            m = _TRACE.match(line)
            if m is None:
                continue
            pc = int(m.group(1), 16)
            if pc == begin:
                current = 0
            elif pc == end and current is not None:
                counts.append(current)
                current = None
            if current is not None:
                current += 1
    return counts


# --- the cost measurement (tests/test_mcu_cost.py, bench/bench_mcu.py) ---

#: The calls tests/mcu/cost_main.c measures, in its order (keep both in step). Steps: "idle",
#: "hold", "run"; the rest are transitions and calls: "start" (phoid_start, IDLE or DONE ->
#: HOLD), "release" (the step that enters RUN: hold_samples reached, or after phoid_release),
#: "clip" (a RUN step that starts a clipping episode: an event), "done" (the step that ends the
#: run), "release-call" (phoid_release), "fault" (a step that trips fault-position), "clear"
#: (phoid_clear_fault), "abort" (phoid_abort in HOLD).
COST_SEQUENCE = (
    "idle", "start", "hold", "hold", "hold", "release", "run", "clip", "run", "run", "done",
    "start", "hold", "release-call", "release", "run", "fault", "clear", "abort",
)
STEP_KINDS = frozenset({"idle", "hold", "run"})
AVR_CLOCK_HZ = 16_000_000  # an Arduino Mega 2560's crystal


def build_cost_firmware(target: Target, out_dir: Path, defines: tuple[str, ...] = ()) -> Path:
    """Compile and link tests/mcu/cost_main.c with the controller for a target (-O2, the
    strict flags for the firmware's own files; ``defines``: more -D flags, e.g. the
    controller's sizes), returning the ELF."""
    need_real(target)
    start = compile_sources(target, [start_file(target)], out_dir, strict=False)
    rest = compile_sources(target, firmware_sources("cost_main"), out_dir, extra=defines)
    return link(target, [*start, *rest], out_dir / "cost.elf")


def _avr_cycles(elf: Path) -> list[int]:
    """Run the AVR cost firmware on simavr, returning the Timer1 counts it printed."""
    simavr = tool("simavr")
    out = run_tool(
        [simavr, "-m", "atmega2560", "-f", str(AVR_CLOCK_HZ), str(elf)],
        f"running {elf.name} on simavr", timeout=60, stderr=True,
    )
    if "exit 0" not in out:
        pytest.fail(f"the AVR cost firmware did not finish: {out[-2000:]}", pytrace=False)
    if "overflow" in out:
        pytest.fail("a measured call took 65536 cycles or more (Timer1 overflowed)",
                    pytrace=False)
    return [int(v) for v in re.findall(r"cycles (\d+)", out)]


def measure_cost(
    target: Target, out_dir: Path, defines: tuple[str, ...] = ()
) -> list[tuple[str, int]]:
    """The cost of each call of ``COST_SEQUENCE`` on a target: instructions executed on its
    QEMU board (Cortex-M), CPU cycles on simavr (AVR); the markers' own cost (an empty pair)
    subtracted.

    Parameters
    ----------
    target : Target
        The build.
    out_dir : Path
        A folder for the objects, the firmware and the trace.
    defines : tuple of str
        More -D flags for the firmware and the controller.

    Returns
    -------
    list of (str, int)
        (kind, count) in the order of ``COST_SEQUENCE``.
    """
    if target.arch == "avr":
        tool("simavr")
    else:
        tool("qemu-system-arm")
    elf = build_cost_firmware(target, out_dir, defines)
    if target.arch == "avr":
        counts = _avr_cycles(elf)
    else:
        log = out_dir / "trace.log"
        qemu_trace(target, elf, log)
        counts = marked_counts(
            symbol_address(target, elf, "mcu_mark_begin"),
            symbol_address(target, elf, "mcu_mark_end"), log,
        )
        log.unlink()  # megabytes: not kept
    if len(counts) != len(COST_SEQUENCE) + 1:
        pytest.fail(
            f"{target.name}: {len(counts)} marked calls, expected {len(COST_SEQUENCE) + 1}",
            pytrace=False,
        )
    empty = counts[0]
    return [(kind, n - empty) for kind, n in zip(COST_SEQUENCE, counts[1:], strict=True)]


# --- division on the step path (tests/test_mcu_build.py) ---

#: Divide instructions: ARMv7-M's integer sdiv/udiv and the FPU's vdiv.f32/.f64 (AVR has none).
DIVIDE_INSTRUCTION = re.compile(r"^(sdiv|udiv|vdiv)(\.|$)")
#: The compiler runtime's division and remainder routines: ARM EABI __aeabi_uidiv(mod),
#: __aeabi_idiv(mod), __aeabi_(u)ldivmod, __aeabi_ddiv/fdiv/drdiv/frdiv; GNU __divsf3,
#: __divdf3, __udivsi3, __umodsi3, __divdi3; AVR __udivmodqi4/hi4/si4, __divmodhi4/si4.
DIVIDE_ROUTINE = re.compile(r"^__\w*(div|mod)\w*$")
_FUNCTION = re.compile(r"^([0-9a-f]+) <([^>]+)>:$")
_INSTRUCTION = re.compile(r"^\s*([0-9a-f]+):\t[0-9a-f ]+\t(\S+)\s*(.*)$")
_RELOCATION = re.compile(r"^\s*([0-9a-f]+): (R_\w+)\s+(\S+)$")
_BRANCH = re.compile(r"^(b|bl|blx|b\.w|b\.n|cbn?z|call|rcall|jmp|rjmp)$")
_TARGET = re.compile(r"<([^>+]+)(\+0x[0-9a-f]+)?>")
_BRANCH_RELOCATION = re.compile(r"^R_(ARM_(THM_)?(CALL|JUMP\d+)|AVR_(CALL|13_PCREL))$")


def step_path_divisions(
    target: Target, obj: Path, roots: tuple[str, ...] = ("phoid_step", "phoid_step_force")
) -> tuple[set[str], list[str]]:
    """The divisions on the step path of a compiled controller: the functions of ``obj``
    reachable from ``roots`` by calls and jumps (``objdump -dr``: the relocations name the
    runtime routines and, on AVR, the object's own static functions as section + offset),
    and every divide instruction or division routine they use.

    Parameters
    ----------
    target : Target
        The build (its objdump).
    obj : Path
        The compiled object (phoid_ctrl.o).
    roots : tuple of str
        The entry points.

    Returns
    -------
    set of str
        The object's functions on the path (the roots included): a guard that the
        disassembly was read.
    list of str
        One "function: instruction or routine" per division found (empty: none).
    """
    objdump = tool(target.prefix + "objdump")
    listing = run_tool([objdump, "-dr", str(obj)], f"disassembling {obj.name}")
    body: dict[str, list[tuple[str, str]]] = {}  # function -> (mnemonic, operands) lines
    targets: dict[str, list[str]] = {}  # function -> branch targets (symbol or section+offset)
    starts: list[tuple[str, int, str]] = []  # (section, address, function)
    section = current = ""
    pending: tuple[str, str] | None = None  # the last branch (mnemonic, operands) unrelocated
    for line in listing.splitlines():
        if line.startswith("Disassembly of section "):
            section = line.removeprefix("Disassembly of section ").rstrip(":")
            continue
        if m := _FUNCTION.match(line):
            current = m.group(2)
            starts.append((section, int(m.group(1), 16), current))
            body.setdefault(current, [])
            targets.setdefault(current, [])
            pending = None
            continue
        if not current:
            continue
        if m := _RELOCATION.match(line):
            if _BRANCH_RELOCATION.match(m.group(2)):
                targets[current].append(m.group(3))
                pending = None  # the relocation, not objdump's guess, names the target
            continue
        if m := _INSTRUCTION.match(line):
            if pending is not None and (t := _TARGET.search(pending[1])):
                targets[current].append(t.group(1))
            mnemonic, operands = m.group(2), m.group(3)
            body[current].append((mnemonic, operands))
            pending = (mnemonic, operands) if _BRANCH.match(mnemonic) else None
    if pending is not None and current and (t := _TARGET.search(pending[1])):
        targets[current].append(t.group(1))

    def resolve(name: str) -> str:
        """A function of the object for a section + offset target; else the name itself."""
        sec, _, off = name.partition("+")
        candidates = [(a, f) for s, a, f in starts if s == sec]
        if not candidates:
            return name
        at = int(off, 16) if off else 0
        return max((c for c in candidates if c[0] <= at), default=(0, name))[1]

    missing = [r for r in roots if r not in body]
    if missing:
        pytest.fail(f"{obj.name}: no function {', '.join(missing)} in its disassembly",
                    pytrace=False)
    seen: set[str] = set()
    todo = list(roots)
    found: list[str] = []
    while todo:
        fn = todo.pop()
        if fn in seen:
            continue
        seen.add(fn)
        found += [f"{fn}: {mn} {ops}".rstrip() for mn, ops in body[fn]
                  if DIVIDE_INSTRUCTION.match(mn)]
        for name in map(resolve, targets[fn]):
            if name in body:
                todo.append(name)
            elif DIVIDE_ROUTINE.match(name):
                found.append(f"{fn}: calls {name}")
    return seen, sorted(set(found))
