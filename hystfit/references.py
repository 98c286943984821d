"""The papers hystfit is built from, cited in full (for ``hystfit models``/``optimizers``, reports and docs).

Docstrings and model ``reference`` strings name them as "paper 000" … "paper 004" (and, from an
earlier convention, point at ``shared/papers/README.md``, a file outside the repository);
:func:`cite` turns such a text into one a reader of a clone can follow.
"""

from __future__ import annotations

import re

#: paper id → full citation (as far as the papers state it)
PAPERS: dict[str, str] = {
    "000": "\u201cAn improved particle swarm optimization method for parameter identification of the hysteresis "
           "nonlinear dynamic model of a piezoelectric positioning system\u201d (electromechanical model with a "
           "generalized Prandtl\u2013Ishlinskii hysteresis; PI P-721 stage)",
    "001": "A. Ounissi, M. Landry, A. Kaddouri, R. Abdessemed, \u201cPSO Based Parameter Identification of "
           "Colman-Hodgdon Hysteresis Model of a Piezoelectric Actuator and PID Feedback Controller\u201d",
    "002": "\u201cModeling, Comparative Investigation and Compensation for Hysteresis Response of Actuator Using "
           "Nonlinear Transformation\u201d, Actuators 2026, 15(6), 338, doi:10.3390/act15060338",
    "003": "\u201cModeling of piezo-positioning system and sliding mode inverse compensation control\u201d "
           "(Hammerstein model: Prandtl\u2013Ishlinskii + Hankel-matrix identification)",
    "004": "Y. Yan, K. Duan, J. Cui, S. Guo, C. Cui, Y. Zhou, J. Huang, G. Wang, D. Zhang, F. Zhang, \u201cNonlinear "
           "Hysteresis Parameter Identification of Piezoelectric Actuators Using an Improved Gray Wolf Optimizer "
           "with Logistic Chaos Initialization and a Levy Flight Variant\u201d, Micromachines 2025, 16(5), 492, "
           "doi:10.3390/mi16050492",
}

#: paper id → short citation used inline
SHORT: dict[str, str] = {
    "000": "improved-PSO electromechanical model of a piezo positioning system",
    "001": "Ounissi et al., PSO identification of the Coleman–Hodgdon model",
    "002": "Actuators 2026, 15(6), 338",
    "003": "Hammerstein model and sliding-mode inverse compensation of a piezo positioning system",
    "004": "Yan et al., Micromachines 2025, 16(5), 492",
}

_INTERNAL = re.compile(r"\s*;?\s*`{0,2}(?:\.\./)?shared/papers/README\.md`{0,2}\s*;?")
_PAPER = re.compile(r"\bpaper (00[0-4])\b|\b(00[0-4])'s\b")


def cite(text: str) -> str:
    """``text`` without pointers to ``shared/papers/README.md`` and with "paper 00N" followed by its
    short citation (first mention only): ``"paper 002 §4"`` → ``"paper 002 [Actuators 2026, 15(6), 338] §4"``;
    :data:`PAPERS` has the full citations."""
    text = _INTERNAL.sub(lambda m: "; " if m.group(0).strip().startswith(";") and m.group(0).rstrip().endswith(";")
                         else "", text).strip(" ;")
    text = re.sub(r"\(\s*\)", "", text)
    text = re.sub(r"^\((\w+)\)", r"\1 model", text.strip())
    text = re.sub(r"\s{2,}", " ", text)
    done: set[str] = set()

    def expand(m: re.Match) -> str:
        pid = m.group(1) or m.group(2)
        if pid in done:
            return m.group(0)
        done.add(pid)
        return f"{m.group(0)} [{SHORT[pid]}]"

    return _PAPER.sub(expand, text)
