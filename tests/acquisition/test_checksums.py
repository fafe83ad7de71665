from crccheck.crc import Crc16CcittFalse

from acquisition.checksums import crc16_ccitt_false


def test_crc16_check_value_and_independent_oracle():
    assert crc16_ccitt_false(b"123456789") == 0x29B1
    for data in (b"", b"\x00", bytes(range(256)), b"PL\x01\x00"):
        assert crc16_ccitt_false(data) == Crc16CcittFalse.calc(data)
