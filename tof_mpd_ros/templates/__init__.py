"""The package's one page builder: every report's HTML and prose comes from the Jinja2 templates
in this directory, loaded as package data with :mod:`importlib.resources` (so a wheel, a colcon
install or an editable checkout all read the same files).

* ``base.html`` with ``report.css``: the frame and the one stylesheet of every HTML report
  (:mod:`tof_mpd_ros.evaluation.report`, :mod:`tof_mpd_ros.mismatch.report`), which extend it;
* ``paper_comparison.txt``: the benchmark's findings against the paper, as macros fed by the
  measured data (:mod:`tof_mpd_ros.evaluation.benchmark.paper`);
* ``mismatch.txt``: the mismatch tool's sentences (evidence, reasons, the camera's profile, the
  verdict), as macros fed by the facts its modules compute (:mod:`tof_mpd_ros.mismatch.wording`);
* ``mode_disagreement.txt``, ``mismatch_benchmark.txt``, ``demo_summary.txt``: texts laid out
  in lines and columns (the real-data modes' disagreement, the mismatch benchmark's table,
  ``tof-mpd demo``'s summary), rendered as written.

Templates named ``*.html`` are autoescaped pages (:func:`render`, :func:`write_page`). ``*.txt``
are text: sentences as macros (:func:`macros`, one line each through :func:`words`), or, when
the layout is lines, a whole text rendered as written (:func:`render`: one template line is one
line of text; a block tag on a line of its own leaves nothing). The filters below format numbers
the same way in every report.
"""

from __future__ import annotations

import json
import math
import re
from functools import cache
from importlib import resources
from pathlib import Path
from typing import Any

import jinja2

_SPACE_BEFORE_PUNCTUATION = re.compile(r" ([.,;:)])")
#: the characters the reports write for a number that is missing (None) or not a number
MISSING = "–"


def fmt(value: Any, spec: str, scale: float = 1.0) -> str:
    """``format(scale * value, spec)``, or :data:`MISSING` for None and NaN."""
    if value is None or math.isnan(value):
        return MISSING
    return format(scale * value, spec)


def spec(value: Any, format_spec: str) -> str:
    """``format(value, format_spec)``, exactly as an f-string writes ``{value:format_spec}``
    (NaN stays ``"nan"``, unlike :func:`fmt`): ``spec(0.612, ">8.1%")`` -> ``"   61.2%"``."""
    return format(value, format_spec)


def pct(value: float) -> str:
    """A fraction as a percentage with one decimal: 0.305 -> ``"30.5 %"``."""
    return f"{100.0 * value:.1f} %"


def ordinal(n: int) -> str:
    """1 -> ``"1st"``, 2 -> ``"2nd"``, 11 -> ``"11th"``, 23 -> ``"23rd"``."""
    suffix = "th" if 10 <= n % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")
    return f"{n}{suffix}"


def thousands(n: int) -> str:
    """An integer with thousands separators: 20000 -> ``"20,000"``."""
    return f"{n:,}"


def _source(name: str) -> str | None:
    """A template's text from the package data, None when there is no such file."""
    path = resources.files(__name__).joinpath(name)
    return path.read_text(encoding="utf-8") if path.is_file() else None


@cache
def environment(prose: bool = False) -> jinja2.Environment:
    """The Jinja2 environment of the package's reports (created on first use).

    ``prose=False`` (pages, ``*.html``): block tags leave no blank lines behind. ``prose=True``
    (``*.txt``, sentences): the template's whitespace is kept for :func:`words` to collapse, so
    a line break in the template is a space in the text.
    """
    env = jinja2.Environment(
        loader=jinja2.FunctionLoader(_source),
        autoescape=jinja2.select_autoescape(enabled_extensions=("html",),
                                            default_for_string=False, default=False),
        undefined=jinja2.StrictUndefined, trim_blocks=not prose, lstrip_blocks=not prose)
    env.filters.update(fmt=fmt, spec=spec, pct=pct, ordinal=ordinal, thousands=thousands,
                       json=json.dumps, stem=lambda name: Path(name).stem)
    return env


def template_names() -> list[str]:
    """Every template file shipped with the package (for the packaging tests)."""
    return sorted(p.name for p in resources.files(__name__).iterdir()
                  if p.is_file() and p.name.endswith((".html", ".txt", ".css")))


def render(name: str, **context: Any) -> str:
    """Render the template ``name`` (e.g. ``"benchmark.html"``) with ``context``."""
    return environment().get_template(name).render(**context)


def write_page(path: str | Path, name: str, **context: Any) -> Path:
    """Render the HTML template ``name`` into the file ``path`` (UTF-8); returns ``path``."""
    out = Path(path)
    out.write_text(render(name, **context), encoding="utf-8")
    return out


def macros(name: str) -> Any:
    """The macros of a prose template as callables:
    ``words(macros("paper_comparison.txt").best_why(facts))``."""
    return environment(prose=True).get_template(name).module


def words(text: Any) -> str:
    """Prose rendered from a template as one line: every run of whitespace becomes one space,
    and none is left before closing punctuation (``. , ; : )``), so templates may break lines
    and place blocks freely."""
    return _SPACE_BEFORE_PUNCTUATION.sub(r"\1", " ".join(str(text).split()))


__all__ = ["MISSING", "environment", "fmt", "macros", "ordinal", "pct", "render", "spec",
           "template_names", "thousands", "words", "write_page"]
