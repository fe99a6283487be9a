# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The checksums a frame description can name: CRC-8 and CRC-16 in the Rocksoft model, sums, XOR.

A CRC is given by its width, poly, init, refin, refout and xorout, as in the catalogues of CRC
parameters; make_checksum() returns a function from bytes to the check value, table-driven (and
binascii.crc_hqx for the CRC-16 that it computes).
"""
import binascii
from collections.abc import Callable
import functools
import operator

CRC_TYPES = {'crc8': 8, 'crc16': 16}
SUM_TYPES = {'sum8': 8, 'sum16': 16, 'xor8': 8}
CHECKSUM_TYPES = (*CRC_TYPES, *SUM_TYPES, 'none')

Checksum = Callable[[bytes | bytearray], int]


def reflect(value: int, width: int) -> int:
    """Return value with its lowest width bits in reverse order."""
    return int(format(value, f'0{width}b')[::-1], 2)


def _crc_table(width: int, poly: int, reflected: bool) -> tuple[int, ...]:
    """Return the 256 register updates of one byte, MSB first or (reflected) LSB first."""
    top = 1 << (width - 1)
    mask = (1 << width) - 1
    table = []
    for byte in range(256):
        if reflected:
            crc = byte
            for _ in range(8):
                crc = (crc >> 1) ^ poly if crc & 1 else crc >> 1
        else:
            crc = byte << (width - 8)
            for _ in range(8):
                crc = ((crc << 1) ^ poly) if crc & top else crc << 1
        table.append(crc & mask)
    return tuple(table)


def make_crc(width: int, poly: int, init: int, refin: bool, refout: bool,
             xorout: int) -> Checksum:
    """Return the CRC of width 8 or 16 bits with these catalogue parameters."""
    if (width, poly, refin, refout, xorout) == (16, 0x1021, False, False, 0):
        return functools.partial(_crc_hqx, init)  # CRC-16/CCITT-FALSE and kin, in C
    shift = width - 8
    mask = (1 << width) - 1
    if refin:
        table = _crc_table(width, reflect(poly, width), True)
        start = reflect(init, width)
        final_reflect = not refout

        def crc(data: bytes | bytearray) -> int:
            register = start
            for byte in data:
                register = table[(register ^ byte) & 0xFF] ^ (register >> 8)
            return (reflect(register, width) if final_reflect else register) ^ xorout
    else:
        table = _crc_table(width, poly, False)

        def crc(data: bytes | bytearray) -> int:
            register = init
            for byte in data:
                register = table[((register >> shift) ^ byte) & 0xFF] ^ ((register << 8) & mask)
            return (reflect(register, width) if refout else register) ^ xorout
    return crc


def _crc_hqx(init: int, data: bytes | bytearray) -> int:
    return binascii.crc_hqx(data, init)


def _sum8(data: bytes | bytearray) -> int:
    return sum(data) & 0xFF


def _sum16(data: bytes | bytearray) -> int:
    return sum(data) & 0xFFFF


def _xor8(data: bytes | bytearray) -> int:
    return functools.reduce(operator.xor, data, 0)


SUMS: dict[str, Checksum] = {'sum8': _sum8, 'sum16': _sum16, 'xor8': _xor8}
