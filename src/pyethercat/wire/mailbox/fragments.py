"""One fragment reassembler for the mailbox protocols that split messages.

Three protocols cut a message that does not fit one mailbox into fragments,
each with its own header fields but the same rules:

=============  =========================  ==========================  ===================
protocol       stays the same             counts                      ends with
=============  =========================  ==========================  ===================
SDO info       opcode                     fragments left, down by 1   incomplete bit 0
SoE            opcode                     fragments left, downwards   incomplete bit 0
EoE            frame number               fragment number, up by 1    last-fragment bit
=============  =========================  ==========================  ===================

(The fields as Wireshark's ``plugins/epan/ethercat/packet-ecatmb.c`` decodes
them; the senders in IgH ``master/fsm_coe.c`` and ``master/fsm_soe.c``, SOEM
``src/ec_soe.c`` and ``src/ec_eoe.c``.)

:class:`FragmentReassembler` holds those rules once; each protocol's own
reassembler (``SdoInfoReassembler``, ``SoeReassembler``, ``EoeReassembler``)
reads its header fields and hands them over. Pure: bytes in, the whole message
out, no clock (the caller's transfer time-out bounds a message that never
ends).
"""

from __future__ import annotations

from collections.abc import Hashable

from pyethercat.errors import MailboxError

__all__ = ["DEFAULT_MESSAGE_LIMIT", "FragmentReassembler"]

#: Largest reassembled message accepted by default. The longest legitimate
#: ones are an SDO-information OD list (2 + 2 x 65535 bytes) and an SoE list
#: (4 + 65532 bytes); a peer sending more is broken, not large.
DEFAULT_MESSAGE_LIMIT = 1 << 20


class FragmentReassembler:
    """Join the fragments of one message at a time.

    ``what`` names the protocol in errors; ``key_name``/``sequence_name`` name
    the header fields compared. ``step`` is how the sequence value moves from
    one fragment to the next (+1 counting up, -1 counting down); ``strict``
    False only requires it to move in that direction (senders disagree about
    the exact SoE count: IgH counts the fragments left, SOEM the full ones).
    A failed check raises :class:`MailboxError` and forgets the message.
    """

    def __init__(self, what: str, *, key_name: str, sequence_name: str, step: int,
                 strict: bool = True, limit: int = DEFAULT_MESSAGE_LIMIT) -> None:
        if step not in (1, -1):
            raise ValueError("step is +1 or -1")
        self.what = what
        self.key_name = key_name
        self.sequence_name = sequence_name
        self.step = step
        self.strict = strict
        self.limit = limit
        #: Messages given up because a new one started before they ended.
        self.dropped = 0
        self._parts: list[bytes] = []
        self._size = 0
        self._key: Hashable = None
        self._sequence: int | None = None
        self._capacity = 0
        self._active = False

    @property
    def in_progress(self) -> bool:
        """True while a message is partly received."""
        return self._active

    @property
    def key(self) -> Hashable:
        """The key of the message in progress (None when idle)."""
        return self._key if self._active else None

    @property
    def received(self) -> int:
        """Bytes of the message in progress received so far."""
        return self._size

    def reset(self) -> None:
        """Forget a partial message."""
        self._parts = []
        self._size = 0
        self._key = None
        self._sequence = None
        self._capacity = 0
        self._active = False

    def _fail(self, why: str) -> MailboxError:
        self.reset()
        return MailboxError(f"{self.what}: {why}")

    def feed(self, data: bytes, *, key: Hashable, sequence: int | None, last: bool,
             first: bool | None = None, offset: int | None = None,
             capacity: int = 0) -> bytes | None:
        """Add one fragment; the whole message after its last fragment, else ``None``.

        ``first`` True starts a new message (an unfinished one is dropped and
        counted), False requires one in progress, None starts one only when
        idle. ``sequence`` None skips the sequence check for this fragment
        (the last SoE fragment carries the IDN there). ``offset`` is the byte
        position the fragment claims; ``capacity`` on the first fragment is
        the announced message size (0: not announced).
        """
        if first is None:
            first = not self._active
        if first:
            if self._active:
                self.dropped += 1
            self.reset()
            self._active = True
            self._key = key
            self._capacity = capacity
        else:
            if not self._active:
                raise self._fail(f"{self.sequence_name} {sequence} without the first fragment")
            if key != self._key:
                raise self._fail(f"{self.key_name} {key} inside a message with "
                                 f"{self.key_name} {self._key}")
            if sequence is not None and self._sequence is not None:
                expected = self._sequence + self.step
                if self.strict and sequence != expected:
                    raise self._fail(f"{self.sequence_name} {sequence} where {expected} "
                                     f"was expected")
                if not self.strict and (sequence - self._sequence) * self.step <= 0:
                    raise self._fail(f"{self.sequence_name} {sequence} does not follow "
                                     f"{self._sequence}")
            if offset is not None and offset != self._size:
                raise self._fail(f"fragment offset {offset} bytes, {self._size} received so far")
        if sequence is not None:
            self._sequence = sequence
        self._parts.append(bytes(data))
        self._size += len(data)
        if self._capacity and self._size > self._capacity:
            raise self._fail(f"{self._size} bytes exceed the announced {self._capacity}-byte "
                             f"message")
        if self._size > self.limit:
            raise self._fail(f"message exceeds {self.limit} bytes")
        if not last:
            return None
        whole = b"".join(self._parts)
        self.reset()
        return whole
