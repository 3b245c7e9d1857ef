"""One style for the numbers the commands print: what the number is, what is good, and what to do when it is not,
in one line (issue 34).

Each figure a command prints is declared once as a :class:`Figure` (:data:`FIGURES`); :meth:`Figure.line` gives
``"<what> <value>: <meaning>; good <under|over> <bound>[: <advice>]"``, the advice only when the value is not
good.  The bounds are what a viewer tolerates on a human-sized face, not tuned to any take: a motion error
under 30 % reads as the same performance in side-by-side tests of the protocols (P1, P8), a lip error
under 1.5 mm is under a tenth of a lip's height, a mouth correlation over 0.9 follows every syllable.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Figure", "FIGURES", "figure_line"]


@dataclass(frozen=True)
class Figure:
    """A printed number: its name, unit, meaning, the bound of a good value, and the advice when it is not.

    Attributes
    ----------
    what : str
        Its name as printed (``"motion error"``).
    unit : str
        Appended to the value (``" %"``, ``" mm"``, ``""``).
    meaning : str
        One clause: what the number measures and its scale.
    bound : float
        A good value is at most (``higher=False``) or at least (``higher=True``) this.
    advice : str
        What to do when the value is not good (a command's own advice may replace it).
    digits : int
        Decimals printed.
    """

    what: str
    unit: str
    meaning: str
    bound: float
    advice: str
    higher: bool = False
    digits: int = 1

    def good(self, value: float) -> bool:
        return value >= self.bound if self.higher else value <= self.bound

    def line(self, value: float, advice: str | None = None) -> str:
        """``"<what> <value>: <meaning>; good under <bound>"``, then the advice when the value is not good."""
        v = f"{value:.{self.digits}f}{self.unit}"
        bound = f"good {'over' if self.higher else 'under'} {self.bound:g}{self.unit}"
        verdict = "" if self.good(value) else f", so not good: {advice or self.advice}"
        return f"{self.what} {v}: {self.meaning}; {bound}{verdict}"


#: Every figure the commands print.
FIGURES: dict[str, Figure] = {
    "rel_motion": Figure(
        "motion error", " %", "the share of the true motion that is wrong (0 is perfect, 100 as far off as a "
        "face that does not move)", 30.0, "give more or better key-models (--keys, --keys-from a range-of-motion "
        "take)"),
    "lips_mm": Figure(
        "lip error", " mm", "mean distance of the lip vertices from where they should be", 1.5,
        "the mouth shapes are off: check the shapes that drive it (--shapes) and the landmarks "
        "(faceretarget character inspect)", digits=2),
    "mouth_corr": Figure(
        "mouth correlation", "", "how the character's mouth opening follows the actor's (1 is perfect)", 0.9,
        "check the character's landmarks (faceretarget character inspect FILE --out check.png) and that its "
        "jaw and lip shapes drive (--shapes)", higher=True, digits=3),
    "key_reconstruction": Figure(
        "reconstruction error", " %", "the share of the take's motion the chosen keyshapes cannot rebuild "
        "(0 is perfect)", 20.0, "choose more keyshapes (--k), or select them from a take with every expression "
        "the performance uses"),
}


def figure_line(key: str, value: float, advice: str | None = None) -> str:
    """:meth:`Figure.line` of :data:`FIGURES` ``[key]``."""
    return FIGURES[key].line(value, advice)
