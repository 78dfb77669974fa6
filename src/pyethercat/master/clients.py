"""Mailbox protocol clients: what one is, and which the master makes for every slave.

A client speaks one mailbox protocol (CoE, FoE, EoE, SoE...) to one slave
through that slave's :class:`~pyethercat.master.mailbox.Mailbox`. The master
makes one client of every registered class for every slave with a mailbox
right after a scan (so that unsolicited messages, such as CoE emergencies,
have a taker from the start), and the slave handle finds it by class::

    master.slaves[3].client(CoeClient).upload(0x1018, 1)

A new protocol plugs in with a class that has

- ``mailbox_type``: the :class:`~pyethercat.wire.mailbox.header.MailboxType`
  it speaks (the registry key), and
- ``for_mailbox(mailbox, context)``: a class method that makes the client
  for one slave; ``context`` (:class:`~pyethercat.master.mailbox.ClientContext`)
  carries the slave's position and the master's queue and callback for the
  protocol's unsolicited messages,

and is listed in :data:`DEFAULT_CLIENTS` (or registered at run time with
:func:`register_client`). docs/architecture.md says where the parts of a
protocol go.
"""

from __future__ import annotations

from typing import ClassVar, Protocol, Self

from pyethercat.master.coe import CoeClient
from pyethercat.master.eoe import EoeClient
from pyethercat.master.foe import FoeClient
from pyethercat.master.mailbox import ClientContext, Mailbox
from pyethercat.master.soe import SoeClient
from pyethercat.wire.mailbox.header import MailboxType

__all__ = ["DEFAULT_CLIENTS", "MailboxClient", "register_client", "registered_clients"]


class MailboxClient(Protocol):
    """A mailbox protocol client class (see the module text)."""

    mailbox_type: ClassVar[MailboxType]

    @classmethod
    def for_mailbox(cls, mailbox: Mailbox, context: ClientContext) -> Self:
        """The client for one slave's mailbox."""
        ...


#: The clients every master makes, in this order.
DEFAULT_CLIENTS: tuple[type[MailboxClient], ...] = (CoeClient, FoeClient, SoeClient, EoeClient)

_registry: dict[MailboxType, type[MailboxClient]] = {c.mailbox_type: c for c in DEFAULT_CLIENTS}


def register_client(cls: type[MailboxClient]) -> type[MailboxClient]:
    """Make masters created from now on give every mailbox slave a ``cls`` client.

    A class registered for a mailbox type replaces the one registered before
    it. Usable as a class decorator.
    """
    _registry[cls.mailbox_type] = cls
    return cls


def registered_clients() -> dict[MailboxType, type[MailboxClient]]:
    """The registered client classes by mailbox type (a copy)."""
    return dict(_registry)
