"""Turning steps into English: verb frames, connectives, constraint clauses.

Every conflict instruction is assembled from pieces (a verb frame, noun phrases, prepositional
phrases, trailing clauses), so the pieces a witness points at are exact substrings of the text.
Choices between equivalent frames come from a seeded ``random.Random``: the same seed writes the
same sentence. Instructions stay lower-case without a final period, like LIBERO's own.
"""

from __future__ import annotations

import random
from dataclasses import dataclass, field

# Frames per step kind; {o} object noun phrase, {d} destination prepositional phrase, {it} it/them.
PLACE = (
    "put {o} {d}",
    "place {o} {d}",
    "pick up {o} and place {it} {d}",
    "pick up {o} and put {it} {d}",
    "move {o} {d}",
    "take {o} and put {it} {d}",
    "grab {o} and set {it} down {d}",
)
PLACE_ON = ("set {o} {d}",)
PLACE_IN = ("drop {o} {d}", "stow {o} {d}")
PUSH = ("push {o} {d}", "slide {o} {d}", "shove {o} {d}")
OPEN = ("open {o}", "pull open {o}")
OPEN_DOOR = ("open {o}", "swing open the door of {o}")
CLOSE = ("close {o}", "shut {o}", "push {o} closed")
TURN_ON = ("turn on {o}", "switch on {o}", "turn {o} on")
TURN_OFF = ("turn off {o}", "switch off {o}", "turn {o} off")
GRASPING = ("pick up", "grab", "lift", "take")
"""Frames that need the gripper to close on the object."""

TWO = (
    "{a}, then {b}",
    "{a} and then {b}",
    "first {a}, then {b}",
    "{a}; after that, {b}",
    "{a}, and once that is done, {b}",
    "{a}, and afterwards {b}",
)
THREE = ("{a}, then {b}, and finally {c}", "first {a}, next {b}, then {c}", "{a}, then {b}, then {c}")


def choose(rng: random.Random, options):
    options = list(options)
    return options[rng.randrange(len(options))]


@dataclass
class Clause:
    """One step as written: a frame filled with phrases, plus trailing clauses."""

    kind: str
    obj: str
    dest: str | None = None
    plural: bool = False
    frame: str | None = None
    """Fixed frame (physical verb swaps); otherwise one is chosen for ``kind``."""
    locating: bool = False
    """The object phrase carries a locating modifier ("the bowl behind the stove"): only frames
    that close the object phrase before the destination ("pick up X and put it ...") are used, so
    the modifier cannot be read as where to put it."""
    extras: list[str] = field(default_factory=list)
    text: str = ""
    body: str = ""
    """The clause without its trailing extras."""

    def render(self, rng: random.Random, *, prep: str | None = None) -> str:
        frame = self.frame
        if frame is None:
            options = frames_for(self.kind, prep, self.dest, self.obj)
            if self.locating:
                options = tuple(f for f in options if "{o} and" in f) or options
            frame = choose(rng, options)
        it = "them" if self.plural or self.obj.startswith("both ") else "it"
        dest = self.dest or ""
        if frame.startswith(("move ", "slide ", "shove ")) and dest.startswith(("on the ", "in the ")):
            dest = ("onto " if dest.startswith("on ") else "into ") + dest[3:]  # "move the cup onto the plate"
        self.body = frame.format(o=self.obj, d=dest, it=it).replace("  ", " ").strip()
        self.text = " ".join([self.body, *self.extras]).replace(" ,", ",")
        return self.text

    def grasps(self) -> bool:
        return any(self.text.startswith(v + " ") for v in GRASPING)


def frames_for(kind: str, prep: str | None, dest: str | None, obj: str) -> tuple[str, ...]:
    if kind == "place":
        if prep == "in":
            return PLACE + PLACE_IN
        if prep == "on":
            return PLACE + PLACE_ON
        return ("put {o} {d}", "place {o} {d}", "move {o} {d}")
    if kind == "push":
        return PUSH
    if kind == "open":
        return OPEN if "drawer" in obj else OPEN_DOOR if "microwave" in obj else ("open {o}",)
    if kind == "close":
        return CLOSE
    if kind == "turn_on":
        return TURN_ON
    if kind == "turn_off":
        return TURN_OFF
    raise ValueError(f"no frames for step kind {kind!r}")


def join(texts: list[str], rng: random.Random) -> str:
    if len(texts) == 1:
        return texts[0]
    if len(texts) == 2:
        return choose(rng, TWO).format(a=texts[0], b=texts[1])
    if len(texts) == 3:
        return choose(rng, THREE).format(a=texts[0], b=texts[1], c=texts[2])
    return ", then ".join(texts)


def coordinate(names: list[str]) -> str:
    """ "the soup" / "both the soup and the sauce" / "the soup, the sauce and the milk"."""
    if len(names) == 1:
        return names[0]
    if len(names) == 2:
        return f"both {names[0]} and {names[1]}"
    return ", ".join(names[:-1]) + f" and {names[-1]}"


def bare(noun_phrase: str) -> str:
    return noun_phrase[4:] if noun_phrase.startswith("the ") else noun_phrase


def sentence_start(text: str) -> str:
    return text[:1].upper() + text[1:]
