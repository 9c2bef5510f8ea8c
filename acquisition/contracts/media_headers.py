"""What an image or a recording holds, read from its header before anything is decoded.

Images and recordings arrive from files nobody vouches for: an imported recorder's folder, a
session directory any account may have written. Decoding is where size turns into memory (a
16000 x 16000 PNG of one colour is a few hundred kilobytes and 768 MB once decoded; a small
FLAC of silence can hold hours), so every reader asks this module for the header's figures
first, compares them with what it expects and with the bounds below, and decodes only then.

Image headers are read with Pillow (`Image.open` parses the header and decodes nothing until
asked); recording headers with libsndfile (`soundfile.info` reads no samples).
"""

from __future__ import annotations

import io
import warnings
from dataclasses import dataclass
from pathlib import Path

import soundfile as sf
from PIL import Image, UnidentifiedImageError

from .errors import UserError

MAX_IMAGE_PIXELS = 100_000_000
"""Largest image decoded, pixels (100 megapixels: 300 MB as BGR); every camera micam knows
takes far smaller ones."""
MAX_RECORDING_VALUES = 2**27
"""Largest recording decoded, samples x channels (134 million: 268 MB as 16-bit codes, e.g.
1024 channels of 131 072 samples, or 64 channels of 44 s at 48 kHz)."""

_PARSE_ERRORS = (OSError, ValueError, EOFError, SyntaxError, IndexError, TypeError)
"""What Pillow's and libsndfile's header parsers raise on a damaged header (OSError includes
Pillow's UnidentifiedImageError and soundfile's LibsndfileError)."""


class UnreadableMedia(UserError):
    """A file is not an image or recording of the kind expected, or is too large to decode;
    the message says which figure is wrong (callers add the file's name and the remedy)."""


@dataclass(frozen=True)
class ImageHeader:
    """An image's format (Pillow's name: "PNG", "JPEG", ...) and size in pixels."""

    format: str
    width: int
    height: int


@dataclass(frozen=True)
class RecordingHeader:
    """A recording's container ("WAV", "FLAC", ...), sample format ("PCM_16", "FLOAT", ...),
    sample rate in hertz, samples (frames) and channels."""

    container: str
    subtype: str
    sample_rate_hz: float
    frames: int
    channels: int


def image_header(source: Path | bytes) -> ImageHeader:
    """The format and size of the image in `source` (a file, or its bytes), refusing one of
    more than MAX_IMAGE_PIXELS pixels; nothing is decoded.

    Raises:
        UnreadableMedia: not an image Pillow identifies, or too large.
    """
    stream = io.BytesIO(source) if isinstance(source, bytes) else source
    with warnings.catch_warnings():
        # Pillow warns above its own ceiling (89 MP) and refuses above twice that: the bound
        # here is ours, so its warning is noise and its refusal one more case of "too large".
        warnings.simplefilter("ignore", Image.DecompressionBombWarning)
        try:
            with Image.open(stream) as image:
                header = ImageHeader(str(image.format), *image.size)
        except Image.DecompressionBombError as exc:  # "Image size (N pixels) exceeds ..."
            raise UnreadableMedia(f"its header states more than the {MAX_IMAGE_PIXELS} pixels "
                                  f"micam decodes ({_one_line(exc)})") from None
        except UnidentifiedImageError:
            raise UnreadableMedia("not an image format micam reads (PNG, JPEG, TIFF, BMP, "
                                  "WebP, ...)") from None
        except _PARSE_ERRORS as exc:
            raise UnreadableMedia(f"its header is damaged ({_one_line(exc)})") from None
    if header.width <= 0 or header.height <= 0:
        raise UnreadableMedia(f"its header states {header.width} x {header.height} pixels")
    if header.width * header.height > MAX_IMAGE_PIXELS:
        raise UnreadableMedia(f"its header states more than the {MAX_IMAGE_PIXELS} pixels "
                              f"micam decodes ({header.width} x {header.height})")
    return header


def recording_header(source: Path | bytes) -> RecordingHeader:
    """The container, sample format, rate, length and channels of the recording in `source`
    (a file, or its bytes); no sample is read.

    Raises:
        UnreadableMedia: not a recording libsndfile reads.
    """
    try:
        info = sf.info(io.BytesIO(source) if isinstance(source, bytes) else str(source))
    except (RuntimeError, *_PARSE_ERRORS) as exc:  # LibsndfileError is a RuntimeError too
        raise UnreadableMedia(f"not a sound file libsndfile reads ({_one_line(exc)})") from None
    return RecordingHeader(str(info.format), str(info.subtype), float(info.samplerate),
                           int(info.frames), int(info.channels))


def check_recording_size(frames: int, channels: int) -> None:
    """Refuse to decode `frames` x `channels` samples when that exceeds MAX_RECORDING_VALUES.

    Raises:
        UnreadableMedia: too large.
    """
    if frames * channels > MAX_RECORDING_VALUES:
        raise UnreadableMedia(f"{frames} samples of {channels} channels are more than the "
                              f"{MAX_RECORDING_VALUES} values micam decodes at once")


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__
