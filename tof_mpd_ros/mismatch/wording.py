"""The mismatch tool's words: the macros of the package template ``templates/mismatch.txt``.

The modules compute facts (plain dicts of numbers and names: :func:`.locate.stratum_facts`,
:func:`.analysis.evidence_facts`, :func:`.profile.profile_items`, the reasons of
:attr:`.analysis.Analysis.unexplained`); these two helpers are the package's one way of turning
them into the sentences the analysis keeps and the JSON report stores. Change the words in the
template, not here.
"""

from __future__ import annotations

from typing import Any

from ..templates import macros, words

TEMPLATE = "mismatch.txt"


def phrase(macro: str, *facts: Any) -> str:
    """The template's macro ``macro`` fed with ``facts``, as one line (:func:`.templates.words`:
    the template's line breaks and indentation become single spaces)."""
    return words(getattr(macros(TEMPLATE), macro)(*facts))


def text(macro: str, *facts: Any) -> str:
    """The template's macro ``macro`` fed with ``facts``, whitespace kept as the macro writes
    it (a joined list, the verdict)."""
    return str(getattr(macros(TEMPLATE), macro)(*facts))


__all__ = ["TEMPLATE", "phrase", "text"]
