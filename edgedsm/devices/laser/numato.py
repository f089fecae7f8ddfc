"""Numato Lab USB relay modules (1/2/4/8/16/32 channels; USB CDC, ASCII commands).

Protocol, as in Numato's own sample code (numato/samplecode: ``relayread.py``,
USBGenie ``Relay.java`` and ``NumatoUSBDevice.java``):

* commands are ASCII ending with a carriage return: ``relay on 0\\r``, ``relay off 0\\r``,
  ``relay read 0\\r``; relays 10 and up are named by letters from ``A`` (relay 10 = ``A``,
  11 = ``B`` ...; not hexadecimal, so it runs past ``F``);
* the module echoes every command (the carriage return comes back as ``\\n\\r``), then the
  answer if there is one, each line ending in ``\\n\\r``, then the prompt ``>``::

      relay on 0\\n\\r>            after relay on 0\\r
      relay read 0\\n\\ron\\n\\r>   after relay read 0\\r   (answer "on" or "off")

The driver reads up to the prompt, checks the echo (so a board that answers some other
command's text is caught), and only then reads the answer. The echo also carries ``on`` or
``off``: the answer is taken after the echo, never by searching the whole reply.
"""

from __future__ import annotations

from edgedsm.devices.laser._serial import SerialRelay, hexdump
from edgedsm.errors import DeviceError

PROMPT = b">"
MAX_ANSWER = 64  # longest sane reply: echo + answer + line ends + prompt


def channel_token(channel: int) -> str:
    """Numato's name of a relay: ``0``..``9``, then ``A`` for 10, ``B`` for 11, ... ``V``."""
    if not 0 <= channel <= 31:
        raise ValueError(f"Numato relay must be 0..31, not {channel}")
    return str(channel) if channel < 10 else chr(ord("A") + channel - 10)


def command_text(action: str, channel: int) -> str:
    """``relay on 0`` (without the carriage return); action is on, off or read."""
    if action not in ("on", "off", "read"):
        raise ValueError(f"Numato relay action must be on, off or read, not {action!r}")
    return f"relay {action} {channel_token(channel)}"


def encode_command(action: str, channel: int) -> bytes:
    """The bytes to send: ``relay on 0\\r``."""
    return (command_text(action, channel) + "\r").encode("ascii")


def parse_reply(command: str, reply: bytes) -> str:
    """Check the echo of ``command`` in ``reply`` and return the answer ('' when none).

    ``reply`` runs up to and including the prompt. Raises DeviceError on anything else.
    """
    try:
        text = reply.decode("ascii")
    except UnicodeDecodeError:
        raise DeviceError(f"Numato board answered non-ASCII bytes to {command!r}: "
                          f"{hexdump(reply)}") from None
    if not text.endswith(">"):
        raise DeviceError(f"Numato board's answer to {command!r} has no prompt: {text!r}")
    body = text[:-1]
    if not body.startswith(command):
        raise DeviceError(f"Numato board did not echo {command!r}; it answered {text!r}")
    rest = body[len(command):]
    # The echoed carriage return comes back as "\n\r"; accept "\r\n" too (terminal settings).
    if rest and rest[0] not in "\r\n":
        raise DeviceError(f"Numato board's echo of {command!r} runs on: {text!r}")
    lines = [line for line in rest.replace("\r", "\n").split("\n") if line]
    if len(lines) > 1:
        raise DeviceError(f"Numato board gave several answers to {command!r}: {text!r}")
    return lines[0].strip() if lines else ""


def is_stale_tail(command: str, reply: bytes) -> bool:
    """Whether ``reply`` (up to a prompt) is the rest of an earlier exchange rather than the answer
    to ``command``: a whole echo of another relay command, or a bare ``on``/``off`` answer line,
    without ``command``'s echo. Anything else is left for :func:`parse_reply` to refuse."""
    text = reply.decode("ascii", errors="replace")
    if not text.endswith(">") or command in text:
        return False
    body = text[:-1].replace("\r", "\n").strip("\n")
    lines = [line for line in body.split("\n") if line]
    if not lines:
        return True  # a lone prompt
    return all(line.startswith("relay ") or line in ("on", "off") for line in lines) and len(lines) <= 2


def parse_state(answer: str) -> bool:
    """``on`` -> True, ``off`` -> False; anything else raises DeviceError."""
    if answer == "on":
        return True
    if answer == "off":
        return False
    raise DeviceError(f"Numato board reported relay state {answer!r}, expected 'on' or 'off'")


class NumatoRelay(SerialRelay):
    """Numato USB relay module: ASCII commands with echo, readback via ``relay read``."""

    protocol = "numato"
    supports_readback = True

    def _exchange(self, action: str) -> str:
        command = command_text(action, self.channel)
        deadline = self._send((command + "\r").encode("ascii"))
        reply = self._read_until(PROMPT, MAX_ANSWER, deadline, repr(command))
        # the end of an exchange a signal cut short may arrive after the input was flushed: the
        # board answers in order, so this request's own reply follows it
        if is_stale_tail(command, reply):
            reply = self._read_until(PROMPT, MAX_ANSWER, deadline, repr(command))
        start = reply.find(command.encode("ascii"))
        if start > 0 and is_stale_tail(command, reply[:start]):
            reply = reply[start:]
        return parse_reply(command, reply)

    def _do_switch(self, on: bool) -> None:
        answer = self._exchange("on" if on else "off")
        if answer:
            raise DeviceError(f"{self.description}: unexpected answer {answer!r} to switching")

    def _do_read_state(self) -> bool:
        return parse_state(self._exchange("read"))
