"""Wording tables of the physical operators: how each impossible step is written, and its premise.

Kept apart from :mod:`.physical`, which holds the rules (which entity may be denied which
affordance, which step may carry it, how violations combine into a case), so that module stays
readable and a phrasing can change here without touching the selection. A wording is a pair: for a
manner, its text when it opens the step and when it follows another manner of the same object; for
a rewritten or added step, the step's whole text and the part of it quoted as the violation.
"""

from __future__ import annotations

PREMISES = {
    "foldable": "{E} is rigid and cannot be folded or bent",
    "graspable": "{E} is heavy furniture fixed in the scene: the robot cannot pick it up or carry it",
    "movable": "{E} is heavy furniture fixed in the scene and cannot be pushed anywhere",
    "fits_in": "{E} is larger than {H} and cannot fit inside it",
    "container": "{E} is sealed or solid: nothing can be put inside it",
    "openable": "{E} has no lid, door or drawer: there is nothing to open or close",
    "turnable": "{E} has no switch or knob: it cannot be turned on or off",
}
"""Why each denied affordance is impossible, by its ``needs``: {E} the entity, {H} a holder."""

# Wordings. {O}: the step's object as named by the task; {S}: its plain noun ("the bowl"); {X}: a
# bystander acted on; {H}: a holder; {P}: the fixture a drawer belongs to; {d}: the step's destination.
MANNERS = {
    "rigidity": (("fold {O} in half", "fold {S} in half"), ("bend {O} in half", "bend {S} in half")),
    "articulation": (("open {O}", "open {S}"), ("open up {O}", "open up {S}")),
    "switch": (("switch on {O}", "switch on {S}"), ("turn on {O}", "turn on {S}")),
}
"""Impossible manners of the step's OWN object, each done before the object is put down: (first, named
in full; second, by its plain noun {S}). Never "it" after a manner verb: only a placing verb takes "it"."""
SWITCH_HELD = (("pick up {O}, switch on {S}", "switch on {S}"), ("take {O}, turn on {S}", "turn on {S}"))
"""A switch named first in a step that then puts the object down: picked up first, so "put it" has
its antecedent ("pick up the ketchup, switch on the ketchup and put it in the basket")."""
GRASPING_KINDS = ("rigidity", "articulation")
"""Manners that grasp the object, so a later "put it" has its antecedent; "switch on X and put it"
has none, so a switch comes second or is picked up first (:data:`SWITCH_HELD`)."""
TAILS = {
    "place": ("put it {d}", "place it {d}", "set it down {d}"),
    "push": ("slide it {d}",),
}
"""What follows the manners in the same step: the original action on "it" (the one object handled)."""
NAMED_TAILS = {
    "place": ("put {S} {d}", "place {S} {d}", "set {S} down {d}"),
    "push": ("slide {S} {d}",),
}
"""The tails after a step that brought in a holder: "squeeze the bowl into the ramekin and put it ..."
could mean the ramekin, so the object is named again."""
LIFT_FIRST = {
    "open": (("lift {P} and open {O}", "lift {P}"), ("pick up {P} and open {O}", "pick up {P}")),
    "close": (("lift {P} and close {O}", "lift {P}"), ("pick up {P} and close {O}", "pick up {P}")),
}
"""A fixture moved before it (or its drawer) is operated: the lift comes first, so it is reached."""
RIGID_ALONE = (("fold {X} in half", "fold {X} in half"), ("bend {X} in half", "bend {X} in half"))
OPEN_ALONE = (("open {X}", "open {X}"), ("open up {X}", "open up {X}"))
SWITCH_ALONE = (("switch on {X}", "switch on {X}"), ("turn on {X}", "turn on {X}"), ("turn {X} on", "turn {X} on"))
LIFT_ALONE = (("lift {X}", "lift {X}"), ("pick up {X}", "pick up {X}"), ("lift {X} and set it down again", "lift {X}"))
INTO_ALONE = (("put {X} inside {H}", "{X} inside {H}"), ("stuff {X} inside {H}", "{X} inside {H}"))
