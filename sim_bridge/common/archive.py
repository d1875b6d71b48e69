"""
The ``.npz`` files of the pipeline (demonstrations, segments, DMPs, skills) and their format tags.

One way to write them with their format tag and version, and one way to read them back that
names the file and the key in every error.
"""

from collections.abc import Mapping
import os
from pathlib import Path
from typing import Any
import zipfile

import numpy as np
from numpy.typing import ArrayLike


def save_archive(path: str | os.PathLike[str], arrays: Mapping[str, ArrayLike], fmt: str,
                 version: int, *, compressed: bool = False) -> None:
    """
    Write ``arrays`` to an ``.npz`` file with the keys ``format`` and ``format_version``.

    The file is written beside ``path`` first and then renamed, so a reader never sees half of
    it.

    Parameters
    ----------
    path : str or Path
        Output file (written as given, no suffix added).
    arrays : dict of str to array_like
        The content.
    fmt : str
        Format tag (``'suture_lfd.segments'``).
    version : int
        Format version.
    compressed : bool
        Deflate the arrays (smaller, slower to write).

    """
    path = Path(path)
    arrays = {'format': np.array(fmt), 'format_version': np.array(version), **arrays}
    save: Any = np.savez_compressed if compressed else np.savez
    tmp = path.with_name(path.name + '.part')
    with open(tmp, 'wb') as handle:
        save(handle, **arrays)
    os.replace(tmp, path)


def load_archive(path: str | os.PathLike[str], fmt: str, version: int,
                 what: str) -> dict[str, np.ndarray]:
    """
    Read an ``.npz`` file written by :func:`save_archive` and check its tag and version.

    Parameters
    ----------
    path : str or Path
        The file.
    fmt : str
        Expected format tag.
    version : int
        Expected format version.
    what : str
        What the file is, for messages (``'segment file'``).

    Returns
    -------
    dict of str to ndarray
        Every stored array (``format`` and ``format_version`` included).

    Raises
    ------
    ValueError
        If the file is unreadable, damaged, not an ``.npz`` archive, of another format or of
        another version; the message names the file and the key.

    """
    try:
        data = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise ValueError(f'{path}: not a readable {what} ({exc})') from exc
    if not isinstance(data, np.lib.npyio.NpzFile):
        raise ValueError(f'{path}: not a {what} (expected an .npz archive)')
    try:
        with data:
            arrays = {key: data[key] for key in data.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise ValueError(f'{path}: damaged {what} ({exc})') from exc
    found = str(arrays['format']) if 'format' in arrays else None
    if found != fmt:
        raise ValueError(f"{path}: key 'format' is {found!r}, expected {fmt!r} (not a {what})")
    try:
        got = int(arrays.get('format_version', -1))
    except (TypeError, ValueError):
        got = -1
    if got != version:
        raise ValueError(f"{path}: key 'format_version' is {got}: {what} version {got} is not "
                         f'supported (expected {version})')
    return arrays
