"""Plain-text reports of results (PHO, free decay, forced, friction) and one estimate ± stderr.

The results are taken by duck typing (the attributes each function reads are named in its
docstring): this subpackage never imports the methods that make them.
"""

from __future__ import annotations

import math
from typing import Any

from phoid._notation import WIDTH, fit_width, notation, unit_text
from phoid._output import safe_text
from phoid.reports.statistics import correlation_lines, ratio_text, statistics_lines, symbol

__all__ = [
    "adequacy_lines",
    "fit_statistics_lines",
    "fit_width",
    "forced_text",
    "format_estimate",
    "format_gain",
    "format_number",
    "format_ratio",
    "free_text",
    "friction_text",
    "identification_text",
    "text_table",
]

# fixed-point notation is used between these magnitudes; beyond them exponent notation
_FIXED_MIN, _FIXED_MAX = 1e-4, 1e9


def format_number(value: float, decimals: int = 4) -> str:
    """``value`` with ``decimals`` decimals, in exponent notation when very large or small.

    Fixed-point notation of 1e300 has 300 digits and that of 1e-300 shows 0: between 1e-4 and
    1e9 in magnitude (and 0) the value is printed with ``decimals`` decimals, beyond them with
    ``decimals`` decimals of the mantissa (``1.0000e+300``); inf and nan as they are.

    Parameters
    ----------
    value : float
    decimals : int

    Returns
    -------
    str

    Examples
    --------
    >>> format_number(0.98765)
    '0.9877'
    >>> format_number(1e300, 2)
    '1.00e+300'
    """
    value = float(value)
    if not math.isfinite(value) or value == 0 or _FIXED_MIN <= abs(value) < _FIXED_MAX:
        return f"{value:.{decimals}f}"
    return f"{value:.{decimals}e}"


def text_table(columns: list[tuple[str, str]], rows: list[list[str]], *, width: int = WIDTH,
               indent: int = 2, label_width: int = 20, left: int = 1) -> list[str]:
    """A table of text cells no wider than ``width``: names in a header row, units in a row
    below, the first ``left`` columns (the first: the row's label) left-aligned and the others
    right-aligned.

    The one layout of phoid's text tables (identification, design, rehearsal, trend, Table 1).

    Columns that do not fit beside the label are wrapped into a further block below (the
    label repeated), and a label longer than ``label_width`` gets a line of its own, the
    row's cells on the next line: no line is wider than ``width`` unless a single cell is.

    Parameters
    ----------
    columns : list of (name, unit)
        The header; ``unit`` "" for none (a block's units row is left out when none of its
        columns, the label's included, has one).
    rows : list of list of str
        The cells, already formatted, one per column; a row may have one more, a note printed
        after the last block's cells (e.g. "set aside").
    width, indent, label_width, left : int

    Returns
    -------
    list of str
    """
    if not columns:
        return []
    n = len(columns)
    gap = "  "
    columns = [(notation(name), notation(unit_text(unit))) for name, unit in columns]
    cells = [[notation(str(c)) for c in r[:n]] + [""] * (n - len(r[:n])) for r in rows]
    notes = [notation(str(r[n])) if len(r) > n else "" for r in rows]
    widths = [max([len(columns[j][0]), len(columns[j][1]), *(len(r[j]) for r in cells)])
              for j in range(n)]
    lab = min(widths[0], label_width)
    # greedy blocks of the other columns, each fitting beside the label
    blocks: list[list[int]] = []
    room = width - indent - lab
    for j in range(1, n):
        need = len(gap) + widths[j]
        if blocks and sum(len(gap) + widths[i] for i in blocks[-1]) + need <= room:
            blocks[-1].append(j)
        else:
            blocks.append([j])
    blocks = blocks or [[]]
    pad = " " * indent
    out: list[str] = []
    for b, block in enumerate(blocks):
        if b:
            out.append("")
        last = b == len(blocks) - 1

        def line(label: str, row: list[str], block: list[int] = block) -> str:
            return (pad + f"{label:<{lab}}" + "".join(
                gap + (f"{row[j]:<{widths[j]}}" if j < left else f"{row[j]:>{widths[j]}}")
                for j in block)).rstrip()

        out.append(line(columns[0][0], [c[0] for c in columns]))
        if any(columns[j][1] for j in (0, *block)):  # no units row without a unit in it
            out.append(line(columns[0][1], [c[1] for c in columns]))
        for r, note in zip(cells, notes, strict=True):
            if len(r[0]) > lab:
                out.append((pad + r[0]).rstrip())
            out.append(line("" if len(r[0]) > lab else r[0], r))
            if note and last:  # after the row, or below it where it would not fit
                if len(out[-1]) + 2 + len(note) <= width:
                    out[-1] += f"  {note}"
                else:
                    out.append(f"{pad}{'':<{lab}}  {note}")
    return out


def format_gain(value: float) -> str:
    """A gain (P, D, a bias) exactly as given: the shortest decimal that reads back as the same
    float (Python's ``repr``, as the rig protocol sends it), without a trailing ``.0``.

    Parameters
    ----------
    value : float

    Returns
    -------
    str

    Examples
    --------
    >>> format_gain(12.625)
    '12.625'
    >>> format_gain(3.0)
    '3'
    >>> format_gain(0.1 + 0.2)
    '0.30000000000000004'
    """
    text = repr(float(value))
    return text[:-2] if text.endswith(".0") else text


def format_ratio(numerator: float, denominator: float, digits: int = 3) -> str:
    """``numerator / denominator`` to ``digits`` significant digits, also where the quotient
    overflows (a 5e-324 s delay against a 1 ms sample step): computed from the logarithms.

    Parameters
    ----------
    numerator, denominator : float
        Finite and > 0 (anything else is printed as the plain quotient).
    digits : int

    Returns
    -------
    str

    Examples
    --------
    >>> format_ratio(1e-3, 5e-324)
    '2.02e+320'
    >>> format_ratio(3.0, 2.0)
    '1.5'
    """
    a, b = float(numerator), float(denominator)
    with_floats = a / b if b != 0 else math.inf
    if (math.isfinite(with_floats) and with_floats != 0) or not (
            math.isfinite(a) and math.isfinite(b) and a > 0 and b > 0):
        return f"{with_floats:.{digits}g}"
    exponent = math.log10(a) - math.log10(b)
    whole = math.floor(exponent)
    mantissa = 10.0 ** (exponent - whole)
    if round(mantissa, digits - 1) >= 10.0:
        mantissa, whole = mantissa / 10.0, whole + 1
    return f"{mantissa:.{digits - 1}f}e{whole:+03d}"


def format_estimate(value: float, se: float | None) -> str:
    """``value ± se`` rounded to the standard error's first two significant digits.

    Parameters
    ----------
    value : float
        The estimate.
    se : float or None
        Its standard error; None, non-finite or ≤ 0 prints ``value`` alone (6 significant
        digits). A standard error below the value's double-precision resolution prints the
        value to 17 significant digits (all a float64 has), not to the stderr's place. Where
        the larger of the value and the stderr is below 1e-4 or from 1e9 on in magnitude, the
        value is printed in exponent notation (its mantissa to the stderr's place), never as
        hundreds of digits.

    Returns
    -------
    str

    Examples
    --------
    >>> format_estimate(2.000123, 0.0042)
    '2.0001 ± 0.0042'
    >>> format_estimate(64.0, None)
    '64'
    >>> format_estimate(2.0, 1e-300)
    '2 ± 1e-300'
    """
    if se is None or not math.isfinite(se) or se <= 0:
        return f"{value:.6g}"
    # the place of the stderr's second significant digit, and of the value's first
    se_exp = math.floor(math.log10(se))
    lead = math.floor(math.log10(abs(value))) if math.isfinite(value) and value else se_exp
    if not math.isfinite(value) or max(abs(value), se) >= _FIXED_MAX or (
            max(abs(value), se) < _FIXED_MIN):
        # exponent notation: the mantissa to the stderr's place, at most the 17 significant
        # digits a float64 has (a value of 1e300 or of 1e-300 has no useful fixed-point form)
        shown = min(16, max(1, lead - se_exp + 1))
        return f"{value:.{shown}e} ± {se:.2g}"
    digits = max(0, 1 - se_exp)
    # significant digits that fixed-point notation would print: beyond 17 they are not the
    # float's (and a tiny stderr would ask for hundreds of them)
    if lead + 1 + digits > 17:
        return f"{value:.17g} ± {se:.2g}"
    return f"{value:.{digits}f} ± {se:.2g}"


def identification_text(ident: Any) -> str:
    """Plain-text report of an identification: estimates, derived ζ and ω₀, runs, warnings.

    Parameters
    ----------
    ident : phoid.Identification or alike
        Read: ``source``, ``delay``, ``delay_stderr``, ``delay_source``, ``delay_from``
        (optional), ``digital`` (optional), ``fit.estimator``, ``m``, ``c``, ``k``, ``omega0``,
        ``zeta`` (each with ``value``, ``stderr``, ``unit``), ``runs``, ``warnings``,
        ``residual_noise_ratios()`` (one per run, or None) and ``fit_statistics()`` (read as by
        :func:`fit_statistics_lines`).

    Returns
    -------
    str
    """
    lines = [f"phoid identify: {safe_text(ident.source)}" if ident.source else "phoid identify"]
    delay = (f"{format_gain(ident.delay)} s" if ident.delay_stderr is None
             else f"{format_estimate(ident.delay, ident.delay_stderr)} s")
    origin = {"x": " from x", "x+u": " from x and u"}.get(getattr(ident, "delay_from", None), "")
    lines.append(f"  estimator {ident.fit.estimator}, delay {delay} ({ident.delay_source}"
                 f"{origin})")
    lines.extend(_digital_line(ident))
    lines.extend(_noise_line(ident))
    lines.append("")
    for name, est in (("m", ident.m), ("c", ident.c), ("k", ident.k)):
        lines.append(f"  {name} = {format_estimate(est.value, est.stderr)} {unit_text(est.unit)}")
    w0, z = ident.omega0, ident.zeta
    zeta = format_estimate(z.value, z.stderr) if math.isfinite(z.value) else "inf (k = 0)"
    lines.append(f"  open-loop ω₀ = {format_estimate(w0.value, w0.stderr)} rad/s,  ζ = {zeta}")
    lines.append("")
    k_u, c_u, x_u = _unit(ident, "N/m"), _unit(ident, "N s/m"), _unit(ident, "m")
    rows = [[safe_text(r.file), format_gain(r.P), format_gain(r.D),
             format_estimate(r.sigma, r.sigma_stderr),
             format_estimate(r.omega_d, r.omega_d_stderr), f"{r.c_prime:.5g}",
             f"{r.k_prime:.5g}", f"{r.cycles:.1f}", f"{r.residual_rms:.2g}", ratio_text(q),
             *([] if r.used else ["(set aside)"])]
            for r, q in zip(ident.runs, ident.residual_noise_ratios(), strict=True)]
    lines.extend(text_table([("run", ""), ("P", k_u), ("D", c_u), ("σ ± stderr", "1/s"),
                             ("ω_d ± stderr", "rad/s"), ("c′", c_u), ("k′", k_u),
                             ("cycles", ""), ("resid", x_u), ("resid/noise", "")], rows))
    lines.extend(fit_statistics_lines(ident))
    lines.extend(adequacy_lines(ident))
    if ident.warnings:
        lines.append("")
        lines.append("warnings:")
        lines.extend(f"  - {safe_text(w)}" for w in ident.warnings)
    return "\n".join(lines)


def _unit(result: Any, unit: str) -> str:
    """One of phoid's SI unit strings as the result's x makes it (its ``unit_of``, where it
    has one: N/m is N m/rad for x in rad); the string itself otherwise."""
    unit_of = getattr(result, "unit_of", None)
    return str(unit_of(unit)) if callable(unit_of) else unit


def fit_statistics_lines(result: Any) -> list[str]:
    """The ``[[Fit statistics]]`` and ``[[Correlations]]`` blocks of a report (lmfit's layout),
    preceded by an empty line.

    Parameters
    ----------
    result : any identification result
        Read: ``fit_statistics()``, a mapping with ``"statistics"`` and ``"correlation"`` as in
        the result's JSON summary (:mod:`phoid.reports.statistics`).

    Returns
    -------
    list of str
    """
    blocks = result.fit_statistics()
    return ["", *statistics_lines(blocks["statistics"]),
            *correlation_lines(blocks["correlation"])]


def adequacy_lines(result: Any) -> list[str]:
    """The ``[[Adequacy]]`` block of a report: each check passed or failed with its statistic
    and threshold, and which stderr the estimates carry (preceded by an empty line; nothing
    when the result has no ``adequacy``).

    Parameters
    ----------
    result : any identification result
        Read: ``adequacy`` (None, or with ``checks`` — each ``name``, ``statistic``,
        ``threshold``, ``passed`` (None: not applicable) — ``stderr`` ("white" or "robust"),
        ``names``, ``inflation`` and ``stderr_note`` (optional: why white-noise stderr stand
        where a check failed)), by duck typing.

    Returns
    -------
    list of str
    """
    ad = getattr(result, "adequacy", None)
    if ad is None:
        return []
    lines = ["", "[[Adequacy]]"]
    for c in ad.checks:
        state = "n/a" if c.passed is None else "pass" if c.passed else "FAIL"
        nums = (f"{c.statistic:.4g} (limit {c.threshold:.4g})"
                if math.isfinite(c.statistic) and math.isfinite(c.threshold) else "")
        lines.append(f"    {symbol(c.name):<12}{state:<6}{nums}".rstrip())
    if ad.stderr == "robust":
        infl = ", ".join(f"{symbol(n)} ×{f:.3g}"
                         for n, f in zip(ad.names, ad.inflation, strict=True))
        lines.append(f"    stderr: robust (Newey–West, widened by the spread between parts where "
                     f"they disagree); over the white-noise stderr: {infl}")
    elif not (failed := [symbol(c.name) for c in ad.checks  # as FAIL is printed above
                          if c.passed is not None and not c.passed]):
        lines.append("    stderr: white-noise least squares (every check passed)")
    else:
        # a check failed but the estimates keep their white-noise stderr: say so, and why
        why = getattr(ad, "stderr_note", "") or "no robust covariance was computed"
        lines.append(f"    stderr: not widened although {', '.join(failed)} failed: {why}")
    return lines


def _digital_line(result: Any) -> list[str]:
    """The sampled loop's description, when the result was computed with one."""
    g = getattr(result, "digital", None)
    if g is None:
        return []
    filt = f", cut-off {format_gain(g.cutoff)} rad/s" if g.cutoff is not None else ""
    return [f"  digital loop (exact sampled model): T_s = {format_gain(g.sample_time)} s, "
            f"{g.delay_samples}-sample delay, {g.velocity} velocity{filt}"]


def _noise_line(result: Any) -> list[str]:
    """Where the sensor noise was taken to enter and why, for a digital loop (a continuous
    loop has one route: its ``noise_placement_source`` is "continuous loop")."""
    source = getattr(result, "noise_placement_source", None)
    if getattr(result, "digital", None) is None or source in (None, "continuous loop"):
        return []
    test = getattr(result, "placement_test", None)
    why = {"manifest": "stated by [loop] noise", "option": "as asked"}.get(source, "")
    if source == "data":
        why = "chosen by the data"
        if test is not None and callable(getattr(test, "words", None)):
            why = safe_text(test.words(result.noise_placement))
    if source == "data" and getattr(test, "noise_free", False):
        return ["  noise-free records (no noise placement to choose): m, c, k from the output "
                "error of the plant driven by the applied force"]
    if result.noise_placement == "in-loop":
        return [f"  noise in the loop ({why}): m, c, k from the output error of the plant "
                "driven by the applied force"]
    return [f"  noise outside the loop ({why}): m, c, k from the runs' modes"]


def friction_text(fit: Any) -> str:
    """Plain-text report of a friction fit.

    Parameters
    ----------
    fit : phoid.FrictionFit or alike
        Read: ``delay``, ``chi2_red``, ``converged``, ``digital`` (optional), ``m``, ``c``,
        ``k``, ``fc`` (each with ``value``, ``stderr``, ``unit``), ``runs``, ``warnings``,
        ``residual_noise_ratios()`` and ``fit_statistics()``.

    Returns
    -------
    str
    """
    lines = ["phoid identify --friction (full-record fit through the stick–slip simulator)"]
    lines.append(f"  delay {format_gain(fit.delay)} s (given), χ²/dof {fit.chi2_red:.3g}, "
                 f"{'converged' if fit.converged else 'NOT converged'}")
    lines.extend(_digital_line(fit))
    if any(getattr(r, "bias", 0.0) for r in fit.runs):
        lines.append("  command bias b·sign(velocity) per run (the seed's DC offset), N: "
                     + ", ".join(format_gain(r.bias) for r in fit.runs))
    lines.append("")
    for name, est in (("m", fit.m), ("c", fit.c), ("k", fit.k), ("fc", fit.fc)):
        lines.append(f"  {name} = {format_estimate(est.value, est.stderr)} {unit_text(est.unit)}")
    lines.append("")
    k_u, c_u, x_u = _unit(fit, "N/m"), _unit(fit, "N s/m"), _unit(fit, "m")
    rows = [[safe_text(r.name), format_gain(r.P), format_gain(r.D), f"{r.sigma:.4g}",
             f"{r.omega_d:.5g}", f"{r.x0:.3g}",
             f"{r.stick_time:.4g}" if r.stick_time is not None else "-",
             f"{r.residual_rms:.2g}", ratio_text(q), *([] if r.used else ["(set aside)"])]
            for r, q in zip(fit.runs, fit.residual_noise_ratios(), strict=True)]
    lines.extend(text_table([("run", ""), ("P", k_u), ("D", c_u), ("σ", "1/s"),
                             ("ω_d", "rad/s"), ("x0", x_u), ("sticks at", "s"),
                             ("resid", x_u), ("resid/noise", "")], rows))
    lines.extend(fit_statistics_lines(fit))
    lines.extend(adequacy_lines(fit))
    if fit.warnings:
        lines.append("")
        lines.append("warnings:")
        lines.extend(f"  - {safe_text(w)}" for w in fit.warnings)
    return "\n".join(lines)


def free_text(result: Any) -> str:
    """Plain-text report of a free-decay identification: σ, ω₀, ζ, roots, c/m, k/m, runs.

    Parameters
    ----------
    result : phoid.methods.free.FreeIdentification or alike
        Read: ``source``, ``sigma`` (1/s), ``omega0`` (rad/s), ``zeta``, ``c_over_m`` (1/s),
        ``k_over_m`` (1/s²) (each with ``value``, ``stderr``, ``unit``), ``regime``, ``roots``
        (two complex, 1/s) and ``roots_stderr`` (per root the stderr of its real and
        imaginary parts, or None), ``m``, ``c``, ``k`` (each an estimate as above, or None
        without a known mass), ``runs`` (each with ``file``, ``release`` (s), ``held``,
        ``x0`` (m), ``v0`` (m/s), ``n_samples``, ``residual_rms`` (m), ``used``), ``warnings``,
        ``residual_noise_ratios()`` and ``fit_statistics()``; ``x_unit`` (optional, default
        ``"m"``: ``"rad"`` or a sensor unit labels the run columns, x0, v0, resid, with it).

    Returns
    -------
    str
    """
    # x in m, or in rad (a rotational set) or a sensor's unit (V, …): the run columns' unit
    xu = safe_text(str(getattr(result, "x_unit", "m")))
    lines = [f"phoid identify (free decay): {safe_text(result.source)}" if result.source
             else "phoid identify (free decay)", ""]
    named = [(notation(n), e) for n, e in (("σ", result.sigma), ("ω₀", result.omega0),
                                            ("ζ", result.zeta), ("c/m", result.c_over_m),
                                            ("k/m", result.k_over_m))]
    label = max(len(n) for n, _ in named) + 1  # "=" aligned in either notation
    for name, est in named:
        val = (format_estimate(est.value, est.stderr) if math.isfinite(est.value)
               else "undefined")
        lines.append(f"  {name:<{label}}= {val} {unit_text(est.unit)}".rstrip())
    lines.append(f"  regime: {result.regime}")
    for j, (s, se) in enumerate(zip(result.roots, result.roots_stderr, strict=True), 1):
        re = format_estimate(s.real, se[0])
        im = format_estimate(abs(s.imag), se[1])
        sign = "+" if s.imag >= 0 else "−"
        re, im = (f"({v})" if "±" in v else v for v in (re, im))
        lines.append(f"  root {j}: {re} {sign} {im}i 1/s")
    if result.m is not None and result.c is not None and result.k is not None:
        what = "moment of inertia J" if result.m.unit == "kg m^2" else "mass m"
        lines.append(f"  with the known {what} = {result.m.value:g} {unit_text(result.m.unit)}:")
        for name, est in (("c", result.c), ("k", result.k)):
            lines.append(f"  {name} = {format_estimate(est.value, est.stderr)} "
                         f"{unit_text(est.unit)}")
    elif getattr(result, "x_unit", "m") not in ("m", "rad"):
        lines.append(f"  (x is in sensor units, {xu}: only σ, ω₀, ζ, c/m and k/m are "
                     "identifiable; c and k need x in a length or an angle unit)")
    else:
        lines.append("  (a free decay gives c/m and k/m, not m, c, k: a known mass (the "
                     "manifest's, --mass) adds c, k)")
    lines.append("")
    rows = [[safe_text(r.file), f"{r.release:.5g}", "yes" if r.held else "no",
             f"{r.x0:.4g}", f"{r.v0:.4g}", f"{r.n_samples:d}", f"{r.residual_rms:.2g}",
             ratio_text(q), *([] if r.used else ["(set aside)"])]
            for r, q in zip(result.runs, result.residual_noise_ratios(), strict=True)]
    lines.extend(text_table([("run", ""), ("release", "s"), ("held", ""), ("x0", xu),
                             ("v0", xu + "/s"), ("samples", ""), ("resid", xu),
                             ("resid/noise", "")], rows))
    lines.extend(fit_statistics_lines(result))
    lines.extend(adequacy_lines(result))
    if result.warnings:
        lines += ["", "warnings:"] + [f"  - {safe_text(w)}" for w in result.warnings]
    return "\n".join(lines)


def forced_text(result: Any) -> str:
    """Plain-text report of a forced identification: m, c, k ± stderr, ω₀, ζ, runs, warnings.

    Parameters
    ----------
    result : phoid.methods.forced.ForcedIdentification or alike
        Read: ``source``, ``m`` (kg), ``c`` (N s/m), ``k`` (N/m) (each with ``value``,
        ``stderr``, ``unit``), ``omega0`` (rad/s) and ``zeta`` (each with ``value`` and
        ``stderr``), ``runs`` (each with ``file``, ``omega`` (rad/s), ``B`` (N), ``C`` (m),
        ``R`` and ``R_stderr`` (N/m), ``rho`` and ``rho_stderr`` (rad), ``t_start`` and
        ``settle_time`` (s), ``used``), ``warnings``, ``residual_noise_ratios()`` and
        ``fit_statistics()``.

    Returns
    -------
    str
    """
    lines = [f"phoid identify (forced): {safe_text(result.source)}" if result.source
             else "phoid identify (forced)", ""]
    for name, est in (("m", result.m), ("c", result.c), ("k", result.k)):
        lines.append(f"  {name} = {format_estimate(est.value, est.stderr)} {unit_text(est.unit)}")
    w0, z = result.omega0, result.zeta
    if math.isfinite(w0.value):
        lines.append(f"  ω₀ = {format_estimate(w0.value, w0.stderr)} rad/s,  "
                     f"ζ = {format_estimate(z.value, z.stderr)}")
    lines.append("")
    rows = [[safe_text(r.file), f"{r.omega:.6g}", f"{r.B:.4g}", f"{r.C:.4g}",
             format_estimate(r.R, r.R_stderr), format_estimate(r.rho, r.rho_stderr),
             f"{r.settle_time - r.t_start:.3g}", ratio_text(q),
             *([] if r.used else ["(set aside)"])]
            for r, q in zip(result.runs, result.residual_noise_ratios(), strict=True)]
    lines.extend(text_table([("run", ""), ("ω", "rad/s"), ("B", _unit(result, "N")),
                             ("C", _unit(result, "m")), ("R ± stderr", _unit(result, "N/m")),
                             ("ρ ± stderr", "rad"), ("settled", "s"), ("resid/noise", "")],
                            rows))
    lines.extend(fit_statistics_lines(result))
    lines.extend(adequacy_lines(result))
    if result.warnings:
        lines += ["", "warnings:"] + [f"  - {safe_text(w)}" for w in result.warnings]
    return "\n".join(lines)
