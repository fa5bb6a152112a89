"""Declared schemas of the TOML documents scanqa reads, and the one validator for them.

Each document's io module declares its keys once, as a :class:`Schema` of
:class:`Field` records (name, type, unit, required, default, limits, what it is);
:meth:`Schema.validate` checks a parsed file against it, and every message comes from
the declaration: it names the file, the key (with the table or entry it sits in) and
the fix. What a schema cannot say (an entry's cross-checks, files that must exist,
a sorted order) stays in the reader, after validation. ``docs/formats.rst`` shows each
schema as a table (:func:`rst_table`; ``tests/test_io_schema.py`` keeps the docs equal
to the declarations). :class:`Field` is scanqa's one field declaration: the scanner
config's keys (:data:`scanqa.model.config.SCHEMA`, validated with the config's own
messages), the per-point value limits of :mod:`scanqa.io.cloud` and the design page's
inputs are Fields too (``tests/test_conventions.py`` finds any other system).

Types are named in words, alternatives joined by " or "::

    Field("z_mm", "number", "mm", required=True, doc="the stage reading")
    Field("phase", "string or strings", doc="decoded phase files, one per repeat")
    Field("target", "table", table=Schema("[target]", (...)))

Only :mod:`scanqa.errors` is imported: io holds formats, no domain.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

from scanqa.errors import InputError, ScanQAError


def _number(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) \
        and math.isfinite(value)


#: The value types a field may have: name -> (test, how a message says it).
TYPES: dict[str, tuple[Callable[[Any], bool], str]] = {
    "string": (lambda v: isinstance(v, str), "a string"),
    "integer": (lambda v: isinstance(v, int) and not isinstance(v, bool), "a whole number"),
    "number": (_number, "a finite number"),
    "boolean": (lambda v: isinstance(v, bool), "true or false"),
    "numbers": (lambda v: isinstance(v, list) and len(v) > 0 and all(map(_number, v)),
                "a non-empty list of finite numbers"),
    "strings": (lambda v: isinstance(v, list) and len(v) > 0
                and all(isinstance(s, str) for s in v), "a non-empty list of strings"),
    "list": (lambda v: isinstance(v, list) and len(v) > 0, "a non-empty list"),
    "table": (lambda v: isinstance(v, dict), "a table"),
    "tables": (lambda v: isinstance(v, list) and all(isinstance(t, dict) for t in v),
               "an array of tables"),
}


@dataclass(frozen=True)
class Check:
    """A limit on a value beyond its type: bounds on a number (on every number of a
    list), a list's length ``n``, or the values allowed (``choices``). ``text`` says it
    ("> 0", "in [0.5, 5000]"), ``noun`` says the type more precisely ("a list of 3
    finite numbers"), :meth:`test` tests it."""

    gt: float | None = None
    ge: float | None = None
    le: float | None = None
    n: int | None = None
    choices: tuple = ()

    @property
    def text(self) -> str:
        """The limit in words, for messages and the docs."""
        if self.choices:
            return "one of " + ", ".join(map(repr, self.choices))
        low = self.ge if self.gt is None else self.gt
        if low is not None and self.le is not None:
            return f"in {'(' if self.gt is not None else '['}{_num(low)}, {_num(self.le)}]"
        return " ".join(f"{op} {_num(b)}" for op, b in
                        ((">", self.gt), (">=", self.ge), ("<=", self.le)) if b is not None)

    @property
    def noun(self) -> str:
        """The type, when the limit says it more precisely than the field's type."""
        return f"a list of {self.n} finite numbers" if self.n else ""

    def test(self, value: Any) -> bool:
        """Whether ``value`` (a number, or a list of numbers) keeps the limit."""
        if self.choices:
            return value in self.choices
        return (self.n is None or len(value) == self.n) and all(
            (self.gt is None or x > self.gt) and (self.ge is None or x >= self.ge)
            and (self.le is None or x <= self.le)
            for x in (value if isinstance(value, list) else [value]))


def _num(x: float) -> str:
    """A bound as text: whole numbers in full (2147483647), others as %g."""
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e15 else f"{x:g}"


def greater(bound: float) -> Check:
    """Numbers (or every number of a list) strictly above ``bound``."""
    return Check(gt=bound)


def at_least(bound: float) -> Check:
    """Numbers (or every number of a list) at or above ``bound``."""
    return Check(ge=bound)


def within(low: float, high: float, open_low: bool = False) -> Check:
    """Numbers (or every number of a list) in [low, high] (``open_low``: in (low, high])."""
    return Check(gt=low, le=high) if open_low else Check(ge=low, le=high)


def count(n: int, then: Check | None = None) -> Check:
    """Lists of exactly ``n`` numbers (each also passing ``then``)."""
    return replace(then or Check(), n=n)


def one_of(*choices: Any) -> Check:
    """One of the listed values."""
    return Check(choices=choices)


@dataclass(frozen=True)
class Field:
    """One key of a TOML document.

    Attributes
    ----------
    name : str
        The key.
    type : str
        Its type in words (:data:`TYPES`), alternatives joined by " or ".
    unit : str
        Its unit ("mm", "px", "um", "-", ...; "" for names and tables).
    required : bool
        Whether the key must be present.
    default : object
        The value a missing optional key stands for (None: nothing).
    check : Check, optional
        A limit beyond the type (applied to numbers; a table's content has its own).
    doc : str
        What the value is, for messages and the docs.
    table : Schema, optional
        The keys of a "table" value, or of each entry of a "tables" value.
    """

    name: str
    type: str
    unit: str = ""
    required: bool = False
    default: Any = None
    check: Check | None = None
    doc: str = ""
    table: Schema | None = None

    def __post_init__(self) -> None:
        unknown = [t for t in self.types if t not in TYPES]
        if unknown:
            raise ValueError(f"field {self.name}: unknown type {unknown[0]!r}")

    @property
    def types(self) -> tuple[str, ...]:
        """The alternative types of the value."""
        return tuple(self.type.split(" or "))

    def expected(self) -> str:
        """What a value must be, in words, e.g. 'a finite number > 0 [mm]'."""
        what = " or ".join(TYPES[t][1] for t in self.types)
        if self.check is not None and self.check.noun:
            what = self.check.noun
        limit = f" {self.check.text}" if self.check and self.check.text else ""
        unit = f" [{self.unit}]" if self.unit and self.unit != "-" else ""
        return f"{what}{limit}{unit}"


@dataclass(frozen=True)
class Schema:
    """The keys of one TOML document (or of one table inside it).

    Attributes
    ----------
    document : str
        What the document is ("sweep manifest"); for a table, how messages name it
        ("[target]", "[[position]]").
    fields : tuple of Field
        Its keys, in file order.
    formats : tuple of str
        The values of ``format`` the reader accepts (a document's, not a table's).
    open : bool
        Whether keys not declared are allowed (a table validated elsewhere).
    name_key : str
        For the entries of an array of tables: the key that names an entry in messages
        (``[[sphere]] 2 ('S2'): ...``).
    each : Field, optional
        For an open table: the type, unit and limits of the value of every key not
        declared (its name is the field's name in the docs, e.g. "SETTING").
    """

    document: str
    fields: tuple[Field, ...]
    formats: tuple[str, ...] = ()
    open: bool = False
    name_key: str = ""
    each: Field | None = None

    def field(self, name: str) -> Field:
        """The field named ``name``."""
        return {f.name: f for f in self.fields}[name]

    def value(self, data: dict, name: str) -> Any:
        """The value of key ``name`` in ``data``, or its declared default."""
        return data.get(name, self.field(name).default)

    def validate(self, data: object, path: object, error: type[ScanQAError] = InputError
                 ) -> dict:
        """Check parsed TOML against the schema; return it unchanged.

        Parameters
        ----------
        data : dict
            The parsed document.
        path : str or PathLike
            The file, named first in every message.
        error : ScanQAError subclass
            The exception raised.

        Raises
        ------
        ScanQAError
            ``error`` for the first wrong ``format``, unknown key, missing required key
            or value of the wrong type or out of its limits, naming the file and key.
        """
        if self.formats:
            fmt = data.get("format") if isinstance(data, dict) else None
            if fmt not in self.formats:
                want = ("one of " if len(self.formats) > 1 else "") + ", ".join(
                    map(repr, self.formats))
                raise error(f"{path}: format must be {want} (the {self.document} format), "
                            f"got {fmt!r:.200}")
        fail = lambda msg: error(f"{path}: {msg}")  # noqa: E731
        if not isinstance(data, dict):
            raise fail(f"not a TOML table: {data!r:.80}")
        _check_table(self, data, "", "", fail)
        return data  # type: ignore[return-value]


def _check_table(schema: Schema, data: object, where: str, dotted: str,
                 fail: Callable[[str], Exception]) -> None:
    """Keys and values of one table. ``where`` prefixes messages about the table's keys
    ("[target]: ", "[[block]] 2 (7): "), ``dotted`` the names of its values ("target.",
    or ``where`` again for the entries of an array of tables)."""
    names = [f.name for f in schema.fields]
    unknown = [k for k in data if k not in names]  # type: ignore[union-attr]
    if unknown and not schema.open:
        raise fail(f"{where}unknown key {unknown[0]!r} (known: {', '.join(names)})")
    if schema.each is not None:
        for key in unknown:
            _check_value(replace(schema.each, name=key), data[key], dotted, fail)
    for f in schema.fields:
        if f.name not in data:  # type: ignore[operator]
            if f.required:
                raise fail(f"{where}{f.name} is missing ({f.doc or f.expected()})")
            continue
        _check_value(f, data[f.name], dotted, fail)  # type: ignore[index]


def _label(f: Field, dotted: str) -> str:
    """How a message names a key: ``[name]`` for a table, ``[[name]]`` for entries."""
    if f.types == ("table",):
        return f"[{dotted}{f.name}]"
    if f.types == ("tables",):
        return f"[[{dotted}{f.name}]]"
    return f"{dotted}{f.name}"


def _check_value(f: Field, value: object, dotted: str, fail: Callable[[str], Exception]
                 ) -> None:
    kinds = [t for t in f.types if TYPES[t][0](value)]
    limited = f.check is not None and kinds and kinds[0] in ("number", "integer", "numbers")
    if not kinds or (limited and not f.check.test(value)):  # type: ignore[union-attr]
        doc = f" ({f.doc})" if f.doc else ""
        raise fail(f"{_label(f, dotted)} must be {f.expected()}{doc}, got {value!r:.200}")
    if kinds[0] == "table" and f.table is not None:
        label = f.table.document or f"[{dotted}{f.name}]"
        _check_table(f.table, value, f"{label}: ", f"{dotted}{f.name}.", fail)
    elif kinds[0] == "tables" and f.table is not None:
        for i, entry in enumerate(value):  # type: ignore[arg-type]
            name = entry.get(f.table.name_key) if f.table.name_key else None
            named = f" ({name!r:.80})" if isinstance(name, (str, int)) else ""
            where = f"[[{dotted}{f.name}]] {i + 1}{named}: "
            _check_table(f.table, entry, where, where, fail)


#: Every declared document schema by document name (filled by :func:`declare` as the io
#: modules are imported).
SCHEMAS: dict[str, Schema] = {}


def declare(schema: Schema) -> Schema:
    """Register a document's schema under its name and return it."""
    if schema.document in SCHEMAS and SCHEMAS[schema.document] != schema:
        raise ValueError(f"schema {schema.document!r} declared twice")
    SCHEMAS[schema.document] = schema
    return schema


# --------------------------------------------------------------------------- docs


def rst_table(schema: Schema, prefix: str = "") -> str:
    """The schema as an RST csv-table: key, type, unit, required, default, meaning.

    Keys of tables are listed after their table, as ``table.key`` (``table[].key`` for
    the entries of an array of tables).
    """
    title = schema.document + (
        f" (``format = {' or '.join(map(repr, schema.formats))}``)".replace("'", '"')
        if schema.formats else "")
    out = [f".. csv-table:: {title}",
           "   :header: key, type, unit, required, default, meaning",
           "   :widths: 24, 14, 6, 7, 9, 40", ""]
    for row in _rows(schema, prefix):
        out.append("   " + ", ".join('"' + cell.replace('"', '""') + '"' for cell in row))
    return "\n".join(out) + "\n"


def _rows(schema: Schema, prefix: str) -> list[tuple[str, ...]]:
    rows = []
    for f in schema.fields:
        limit = " ".join(x for x in (f.check.noun, f.check.text) if x) if f.check else ""
        doc = "; ".join(x for x in (f.doc, limit) if x)
        if f.table is not None and f.table.open and f.table.each is None:
            doc = "; ".join(x for x in (doc, "keys checked by its reader") if x)
        value = list(f.default) if isinstance(f.default, tuple) else f.default  # TOML's
        default = "" if value is None else f"``{value!r}``".replace("'", '"')
        unit = "\\-" if f.unit == "-" else f.unit  # a bare "-" is a list item in RST
        rows.append((f"``{prefix}{f.name}``", f.type, unit, "yes" if f.required else "no",
                     default, doc))
        if f.table is not None:
            sub = f"{prefix}{f.name}[]." if "tables" in f.types else f"{prefix}{f.name}."
            each = () if f.table.each is None else (f.table.each,)
            rows += _rows(replace(f.table, fields=(*f.table.fields, *each)), sub)
    return rows
