"""Metavision ``.bias`` files: read and write the sensor biases as Metavision tools do.

Facts (OpenEB ``I_LL_Biases::load_from_file`` / ``save_to_file``):

- the extension must be ``.bias``;
- an optional header of ``%`` lines comes first; then one bias per line, ``VALUE % NAME``
  (decimal, or hexadecimal with ``0x``), up to the first empty line;
- a bias named twice with different values is an error; nothing is set unless the whole file
  reads;
- saving writes every bias sorted by name, the value left-aligned in 5 columns, then ``% NAME``.

The values mean what :meth:`capture.evk.Camera.set_biases` takes for the sensor (IMX636:
offsets from the factory trim, as the HAL's).
"""

from __future__ import annotations

from pathlib import Path


def _check_extension(path: Path) -> None:
    if path.suffix != ".bias":
        raise ValueError(f"bias file {path}: expected the '.bias' extension, got {path.suffix or 'none'!r}")


def read_bias_file(path) -> dict[str, int]:
    """Biases named in a ``.bias`` file, ``{name: value}``.

    Raises
    ------
    ValueError
        A wrong extension, a line that is not ``VALUE % NAME``, a bias given two different values.
    FileNotFoundError
        No such file.
    """
    path = Path(path)
    _check_extension(path)
    lines = path.read_text(encoding="ascii", errors="replace").splitlines()
    i = 0
    while i < len(lines) and lines[i].startswith("%"):
        i += 1  # the header
    out: dict[str, int] = {}
    for line in lines[i:]:
        if not line.strip():
            break
        parts = line.split()
        if len(parts) < 3 or parts[1] != "%":
            raise ValueError(f"bias file {path}: wrong line format {line!r} (expected 'VALUE % NAME')")
        text, name = parts[0].lower(), parts[2]
        try:
            value = int(text, 16) if text.startswith("0x") else int(text)
        except ValueError:
            raise ValueError(f"bias file {path}: {parts[0]!r} is not a number in line {line!r}") from None
        if name in out and out[name] != value:
            raise ValueError(f"bias file {path}: bias {name!r} is given two different values")
        out[name] = value
    return out


def write_bias_file(path, biases: dict[str, int]) -> Path:
    """Write ``biases`` as Metavision saves them (sorted by name); returns the path.

    Raises
    ------
    ValueError
        A wrong extension.
    """
    path = Path(path)
    _check_extension(path)
    path.write_text("".join(f"{int(v):<5d}% {k}\n" for k, v in sorted(biases.items())), encoding="ascii")
    return path


def biases_of(bias_file, named) -> dict[str, int]:
    """Biases to set: those of ``bias_file`` (a ``.bias`` path, or None), overridden by the
    ``(name, value)`` pairs of ``named`` (e.g. ``--bias`` options)."""
    return {**(read_bias_file(bias_file) if bias_file else {}), **dict(named)}
