"""Which links the isolated engine can take into its process."""

from __future__ import annotations

import pickle

from pyethercat.link.base import Link, SocketLink
from pyethercat.link.redundant import RedundantLink

__all__ = ["link_can_move"]


def link_can_move(link: Link) -> str | None:
    """None when ``link`` can be handed to the engine's process, else why not.

    A link over one socket (raw interface, UDP, Unix socketpair) travels as
    its socket's descriptor; an in-process pair (a simulator in this
    process), a capture tee or a ring's two ports do not.
    """
    if isinstance(link, RedundantLink):
        return "a ring's two ports stay with the in-process loop (isolated=False)"
    if not isinstance(link, SocketLink):
        return (f"the link {link.name} ({type(link).__name__}) cannot be handed to another "
                "process (a link over one socket can)")
    # What the plan's pickle takes of it: a link may leave out what a new process makes
    # afresh (a raw link's poll object).
    state = link.__getstate__()
    items = state.items() if isinstance(state, dict) else vars(link).items()
    try:
        pickle.dumps({k: v for k, v in items if k != "_sock"})
    except (pickle.PicklingError, TypeError, AttributeError) as exc:
        return f"the link {link.name} cannot be handed to another process: {exc}"
    return None
