"""Bytes in and out: TF-Luna UART frames and commands, the I2C register map, the
published message schema, and a subscriber client for robot code."""

from lunad.protocol import commands, registers
from lunad.protocol.commands import CommandId, CommandReply, Version, decode_reply
from lunad.protocol.frame import (
    DATA_FRAME_LEN,
    Frame,
    OutputFormat,
    checksum,
    encode_frame,
    temp_raw_from_c,
)
from lunad.protocol.messages import (
    SCHEMA_VERSION,
    HealthMessage,
    Message,
    RangeMessage,
    decode,
    topic,
)
from lunad.protocol.parser import FrameParser, ParserStats

__all__ = [
    "DATA_FRAME_LEN",
    "SCHEMA_VERSION",
    "CommandId",
    "CommandReply",
    "Frame",
    "FrameParser",
    "HealthMessage",
    "Message",
    "OutputFormat",
    "ParserStats",
    "RangeMessage",
    "Version",
    "checksum",
    "commands",
    "decode",
    "decode_reply",
    "encode_frame",
    "registers",
    "temp_raw_from_c",
    "topic",
]
