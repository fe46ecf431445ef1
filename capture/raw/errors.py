"""Exceptions and warnings raised by the RAW codec."""


class RawFormatError(ValueError):
    """The input is not a decodable Prophesee RAW stream.

    Raised for an empty file, a header naming an unknown event format, a
    missing format, bad geometry, or (with ``strict=True``) damaged data. The
    message names the file (when known) and the byte offset of the problem.
    """


class RawDamageWarning(UserWarning):
    """Decoded with damage: words were skipped, events dropped or bytes left over.

    The message names the file, the byte offset of the first damage and the
    counts; the decoded data before and after the damage is kept.
    """
