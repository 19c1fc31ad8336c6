"""The identification methods of the format, one table: what each set's ``method`` runs.

Every way to identify a read experiment set goes through :func:`identify_with`:
:func:`phoid.identify` (the Python keywords), ``phoid identify`` and ``phoid batch``
(:func:`phoid.methods.dispatch.identify_set`, the command line's options). The same mistake
therefore gives the same exception (:class:`~phoid.errors.IdentificationError`, a
``ValueError``) and the same one-line message on every route, the option named in the
caller's words (``--no-compensation`` on the command line, ```compensate=False``` in Python).

:data:`METHODS` holds, per ``method``, its :class:`Variant` s: the function that identifies
the set (a ``"module:function"`` name, imported only when a set of that method is
identified, so that ``import phoid`` and the PHO path load no other method), the options it
takes (:data:`OPTIONS`), the values ``estimator`` may take, the checks of the set made
first, the result class, its text report and the section of docs/format.md its ``--json``
fills. An option such as ``--friction`` selects a variant of its method (``selected_by``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from phoid import _validate as v
from phoid.errors import IdentificationError

__all__ = ["METHODS", "OPTIONS", "Method", "Option", "Variant", "identify_with", "labelled",
           "load", "option"]


@dataclass(frozen=True)
class Option:
    """An identify option, in the command line's and in Python's words.

    Attributes
    ----------
    name : str
        Its keyword of :func:`~phoid.methods.dispatch.identify_set` and of ``phoid batch``.
    flag : str
        The command line's option.
    keyword : str
        :func:`phoid.identify`'s keyword (and that of the methods' functions).
    unset : object
        The value that means "not given" (None, or False for a flag).
    inverted : bool
        ``keyword`` is the negation of the option (``compensate = not no_compensation``).
    kind : str
        ``"number"`` (a real number, or None), ``"text"`` (a string, or None) or ``"flag"``
        (True or False).
    unit : str
        The unit of a number.
    physical : bool
        A number that must be > 0 and of magnitude 1e-30 … 1e30 in ``unit``
        (:func:`phoid._validate.physical`), checked here for every method.
    choices : tuple of str
        The values a text option may take (empty: any string; ``estimator``'s depend on the
        method and are checked per variant).
    """

    name: str
    flag: str
    keyword: str
    unset: Any
    inverted: bool = False
    kind: str = "flag"
    unit: str = ""
    physical: bool = False
    choices: tuple[str, ...] = ()

    def words(self, style: str, value: Any = None) -> str:
        """The option as the caller wrote it: ``"cli"`` (``--estimator ols``) or ``"api"``
        (```estimator='ols'```); ``value`` None names the option alone."""
        if style == "cli":
            return self.flag if value is None or self.kind == "flag" else f"{self.flag} {value}"
        if self.kind == "flag":  # given as True (the API: its keyword's value)
            return f"`{self.keyword}={not self.inverted}`"
        return f"`{self.keyword}`" if value is None else f"`{self.keyword}={value!r}`"


#: the options of ``phoid identify`` (and ``phoid batch``), in the order they are checked
OPTIONS: tuple[Option, ...] = (
    Option("delay", "--delay", "delay", None, kind="number", unit="s"),
    Option("estimator", "--estimator", "estimator", None, kind="text"),
    Option("no_compensation", "--no-compensation", "compensate", False, inverted=True),
    Option("mass", "--mass", "mass", None, kind="number", unit="kg", physical=True),
    Option("friction", "--friction", "friction", False),
    Option("noise", "--noise", "noise_placement", None, kind="text",
           choices=("auto", "in-loop", "outside")),
)


def option(name: str) -> Option:
    """The :class:`Option` called ``name`` (KeyError for an unknown one)."""
    for opt in OPTIONS:
        if opt.name == name:
            return opt
    raise KeyError(name)


@dataclass(frozen=True)
class Variant:
    """One way a method identifies a set.

    Attributes
    ----------
    function : str
        ``"module:function"``, called as ``function(experiment, **keywords)``.
    passes : tuple of str
        The options handed on, as the function's keywords (:attr:`Option.keyword`).
    selected_by : str or None
        A flag option that selects this variant (None: the method's default).
    estimators : tuple of str
        The values ``estimator`` may take (empty: the option does not apply).
    default_estimator : str or None
        ``estimator`` when not given (None: the function's own default).
    requires : tuple of (str, str, str, str)
        ``(option, other, value, why)``: ``option`` given needs ``other`` equal to ``value``.
    checks : tuple of str
        ``"module:function"`` s called as ``check(experiment, method)`` before the function.
    result : str
        ``"module:Class"`` of the result.
    report : str
        ``"module:function"`` of its text report (:mod:`phoid.reports`).
    schema : str
        The heading of docs/format.md whose ``--json`` keys the result's ``summary()`` fills.
    """

    function: str
    passes: tuple[str, ...]
    result: str
    report: str
    schema: str
    selected_by: str | None = None
    estimators: tuple[str, ...] = ()
    default_estimator: str | None = None
    requires: tuple[tuple[str, str, str, str], ...] = ()
    checks: tuple[str, ...] = ()

    def accepts(self, name: str) -> bool:
        """Whether the option ``name`` applies to this variant."""
        return (name in self.passes or name == self.selected_by
                or (name == "estimator" and bool(self.estimators)))


@dataclass(frozen=True)
class Method:
    """A ``method`` of the format and its variants.

    Attributes
    ----------
    name : str
        The manifest's ``method``.
    variants : tuple of Variant
        The default (``selected_by`` None) and those an option selects.
    hints : Mapping[str, str]
        Per option this method refuses, why (appended to the refusal).
    """

    name: str
    variants: tuple[Variant, ...]
    hints: Mapping[str, str] = field(default_factory=dict)

    def accepts(self, name: str) -> bool:
        """Whether the option ``name`` applies to some variant of this method."""
        return any(v.accepts(name) for v in self.variants)


_BIAS = "phoid.methods.pho_checks:refuse_bias"

#: a free decay with Coulomb and viscous friction and its stop (``--friction`` on free sets);
#: its ``--json`` is documented within the free sets' section (``"friction": true``)
FREE_FRICTION = Variant("phoid.methods.free_friction:identify_free_friction", ("mass",),
                        result="phoid.methods.free_friction:FreeFrictionIdentification",
                        report="phoid.reports.free_friction:free_friction_text",
                        schema="`free` sets with `--friction`", selected_by="friction",
                        checks=(_BIAS,))

#: the methods of the format (``phoid.io.METHODS``), by name
METHODS: dict[str, Method] = {m.name: m for m in (
    Method("pho", (
        Variant("phoid.methods.identification:identify_pho",
                ("delay", "estimator", "no_compensation", "noise"),
                result="phoid.methods.pho_result:Identification",
                report="phoid.reports.text:identification_text", schema="`pho` sets",
                estimators=("gls", "ols"), default_estimator="gls",
                requires=(("no_compensation", "estimator", "ols", "the eq. (35) lines"),),
                checks=(_BIAS,)),
        Variant("phoid.methods.friction:identify_friction_set", ("delay", "noise"),
                result="phoid.methods.friction:FrictionFit",
                report="phoid.reports.text:friction_text",
                schema="`pho` sets with `--friction`", selected_by="friction",
                estimators=("gls",), default_estimator="gls"),
    ), hints={"mass": "a PHO set gives m"}),
    Method("forced", (
        Variant("phoid.methods.forced:identify_forced", (),
                result="phoid.methods.forced:ForcedIdentification",
                report="phoid.reports.text:forced_text", schema="`forced` sets",
                checks=(_BIAS,)),
    ), hints={"mass": "a forced set gives m"}),
    Method("free", (
        Variant("phoid.methods.free:identify_free", ("mass",),
                result="phoid.methods.free:FreeIdentification",
                report="phoid.reports.text:free_text", schema="`free` sets",
                checks=(_BIAS,)),
        FREE_FRICTION,
    )),
    Method("tracking", (
        Variant("phoid.methods.tracking_identification:identify_tracking",
                ("delay", "estimator"),
                result="phoid.methods.tracking_identification:TrackingIdentification",
                report="phoid.reports.tracking:identification_text", schema="`tracking` sets",
                estimators=("auto", "idim", "output-error")),
    ), hints={"mass": "its [fixed] table holds known parameters"}),
)}


def load(target: str) -> Any:
    """The object named ``"package.module:name"``, its module imported now.

    Parameters
    ----------
    target : str
        A module's dotted name and a name in it, joined by a colon.

    Returns
    -------
    object
    """
    import importlib

    module, _, name = target.partition(":")
    return getattr(importlib.import_module(module), name)


def _scope(name: str) -> str:
    """The methods an option applies to, in words: "pho and tracking sets"."""
    names = [m.name for m in METHODS.values() if m.accepts(name)]
    return (", ".join(names[:-1]) + " and " + names[-1] if len(names) > 1 else names[0]) + \
        " sets"


def _dtype_kind(value: Any) -> str:
    """A numpy scalar's dtype kind ("b", "i", "u", "f", …); "" for anything else."""
    return str(getattr(getattr(value, "dtype", None), "kind", "") or "")


def _given(opt: Option, value: Any) -> bool:
    """Whether the option was given: a flag not False (a non-bool, None included, is given,
    and refused by :func:`_check_kind`), any other option not None."""
    if opt.kind == "flag":
        return not (value is False or (_dtype_kind(value) == "b" and not value))
    return value is not None


def _check_kind(opt: Option, value: Any, where: str, style: str) -> None:
    """Refuse a value of the wrong type for its option (one line, naming it)."""
    if opt.kind == "flag":
        ok, want = isinstance(value, bool) or _dtype_kind(value) == "b", "True or False"
    elif opt.kind == "number":
        ok = not isinstance(value, bool) and (isinstance(value, int | float)
                                              or _dtype_kind(value) in ("i", "u", "f"))
        want = f"a number, in {opt.unit}"
    else:
        ok, want = isinstance(value, str), "a string"
    name = opt.flag if style == "cli" else f"`{opt.keyword}`"
    if ok and opt.choices and value not in opt.choices:
        ok, want = False, "one of " + ", ".join(map(repr, opt.choices))
    if not ok:
        text = repr(value)
        raise IdentificationError(f"{where}: {name} must be {want}; got "
                                  f"{text if len(text) <= 60 else text[:57] + '...'}")
    if opt.physical:
        try:
            v.physical(name, value, opt.unit)
        except ValueError as exc:
            raise IdentificationError(f"{where}: {exc}") from None


def identify_with(experiment: Any, options: Mapping[str, Any], *, style: str = "cli") -> Any:
    """Identify a read set by its ``method``, with identify options: the one dispatch.

    Parameters
    ----------
    experiment : phoid.io.ExperimentSet
        The set (its ``method``, default ``"pho"``, and ``path``).
    options : Mapping[str, Any]
        Options by :attr:`Option.name` (``delay``, ``estimator``, ``no_compensation``,
        ``mass``, ``friction``, ``noise``); a missing one is not given.
    style : {"cli", "api"}
        The words the messages name the options in.

    Returns
    -------
    object
        The method's result (its ``summary()`` is ``phoid identify --json``), labelled by the
        set (:func:`phoid.methods.registry.labelled`: its units as the set's ``x_unit``
        makes them, the set's ``notes`` among its warnings).

    Raises
    ------
    IdentificationError
        One line naming the set and the option: an unknown method, an option that does not
        apply to the set's method (or to the variant another option chose), an ``estimator``
        the method does not have, an option that needs another (``--no-compensation`` needs
        ``--estimator ols``), a value of the wrong type; and whatever the method refuses.
    """
    where = str(getattr(experiment, "path", None) or "the experiment set")
    unknown = sorted(set(options) - {o.name for o in OPTIONS})
    if unknown:
        raise IdentificationError(f"unknown identify option {unknown[0]!r}; the options are "
                                  f"{', '.join(o.name for o in OPTIONS)}")
    # an option missing from ``options`` is not given; one given as None is, for a flag (and
    # refused by _check_kind: a flag is True or False)
    given = {o.name: options[o.name] for o in OPTIONS
             if o.name in options and _given(o, options[o.name])}
    for name, value in given.items():
        _check_kind(option(name), value, where, style)
    method_name = getattr(experiment, "method", "pho")
    method = METHODS.get(method_name)
    if method is None:
        raise IdentificationError(f"{where}: method = {method_name!r} is not known; the "
                                  f"methods are {', '.join(METHODS)}")
    for name in given:  # an option no variant of the method takes
        if not method.accepts(name):
            hint = method.hints.get(name)
            raise IdentificationError(
                f"{where}: {option(name).words(style)} does not apply to {method.name} sets"
                f"{f' ({hint})' if hint else ''}; it applies to {_scope(name)}")
    chosen = [v for v in method.variants if v.selected_by in given]
    variant = chosen[0] if chosen else next(v for v in method.variants if v.selected_by is None)
    scope = f"{method.name} sets" + (
        f" with {option(variant.selected_by).words(style)}" if variant.selected_by else "")
    for name in given:  # an option the chosen variant does not take
        if not variant.accepts(name):
            raise IdentificationError(f"{where}: {option(name).words(style)} does not apply "
                                      f"to {scope}")
    estimator = given.get("estimator", variant.default_estimator)
    if "estimator" in given and estimator not in variant.estimators:
        known = ", ".join(map(repr, variant.estimators))
        raise IdentificationError(
            f"{where}: {option('estimator').words(style)} must be "
            f"{'one of ' * (len(variant.estimators) > 1)}{known} for {scope}; got "
            f"{estimator!r}")
    values = {**given, "estimator": estimator}
    for name, other, value, why in variant.requires:
        if name in given and values.get(other) != value:
            raise IdentificationError(
                f"{where}: {option(name).words(style)} needs "
                f"{option(other).words(style, value)} on {scope} ({why})")
    for check in variant.checks:
        load(check)(experiment, method.name)
    keywords = {}
    for name in variant.passes:
        opt = option(name)
        value = values.get(name, opt.unset)
        keywords[opt.keyword] = (not value) if opt.inverted else value
    result = load(variant.function)(experiment, **keywords)
    # every method's result labelled by its set, here once: x's unit (J, N m s/rad … for x
    # in rad) and the notes of how the set was read (docs/architecture.md)
    return labelled(result, str(getattr(experiment, "x_unit", "m") or "m"),
                    tuple(getattr(experiment, "notes", ()) or ()))


def _relabelled(value: Any, x_unit: str) -> Any:
    """An :class:`Estimate` with its unit as :func:`~phoid.io.units.quantity_unit` reads it
    (a mapping of estimates, each so); anything else as it is."""
    from dataclasses import replace

    from phoid.io.units import quantity_unit
    from phoid.methods.estimate import Estimate

    if isinstance(value, Estimate):
        unit = quantity_unit(value.unit, x_unit)
        return value if unit == value.unit else replace(value, unit=unit)
    if isinstance(value, Mapping) and value and all(isinstance(v, Estimate)
                                                    for v in value.values()):
        return {k: _relabelled(v, x_unit) for k, v in value.items()}
    return value


def labelled(result: Any, x_unit: str = "m", notes: Sequence[str] = ()) -> Any:
    """A method's result labelled by its set: the one place every method's units follow x.

    :func:`identify_with` calls it on whatever the method returned, so that every method (pho,
    ``--friction``, forced, free, free with ``--friction``, tracking) is labelled the same way,
    whether its result is on :class:`~phoid.methods.result_base.ResultBase` or not. Each
    ``Estimate`` field (and each estimate of a mapping field, a tracking result's
    ``estimates``) gets the unit :func:`phoid.io.units.quantity_unit` gives for ``x_unit`` (x
    in rad: kg → kg m^2, N s/m → N m s/rad, N/m → N m/rad, N → N m; a sensor unit: m → V …);
    an ``x_unit`` field is set (a ``ResultBase`` relabels its fit statistics and adequacy by
    it); and the set's ``notes`` (how it was read: "t rebuilt from sample_rate" …) are
    appended to ``warnings`` where not already there. Units already labelled stay as they are
    (the labels are idempotent).

    Parameters
    ----------
    result : object
        A frozen dataclass result (anything else is returned as it is).
    x_unit : str
        The set's :attr:`phoid.io.ExperimentSet.x_unit`.
    notes : sequence of str
        The set's :attr:`phoid.io.ExperimentSet.notes`.

    Returns
    -------
    object
        A copy of ``result`` with those changes (``result`` itself when there are none).
    """
    from dataclasses import fields, is_dataclass, replace

    if not is_dataclass(result) or isinstance(result, type):
        return result
    names = {f.name for f in fields(result) if f.init}
    changes: dict[str, Any] = {}
    if x_unit != "m":
        for name in names:
            value = getattr(result, name)
            new = _relabelled(value, x_unit)
            if new is not value:
                changes[name] = new
    if "x_unit" in names and result.x_unit != x_unit:
        changes["x_unit"] = x_unit
    if "warnings" in names:
        warnings = tuple(result.warnings or ())
        extra = tuple(str(n) for n in notes if n not in warnings)
        if extra:
            changes["warnings"] = warnings + extra
    return replace(result, **changes) if changes else result
