"""`micam import`: a micam session from what any recorder produces.

Input: one TOML file (`_spec`: the rig and array description plus a `[recordings]` table
naming the files), beside it a folder of recordings (WAV, FLAC, RF64 or anything else
libsndfile reads; HDF5 time data as Acoular writes it: a dataset `time_data` of shape
(samples, channels) with the attribute `sample_freq`, read with h5py) and images (PNG, JPEG,
TIFF, ... whose header Pillow reads and which OpenCV decodes). Output: a session written
through the session store (journal, checksums, atomic files), whose capture is the
description itself, so that `micam calibrate` reads it like any other.

Every field and every file's header is checked before anything is written, and every file's
content with the same code whether the import writes or only checks (`_session`); a mistake
costs nothing but the message, which names the TOML field, what is wrong and what to write
instead. Sizes are bounded from headers before anything is decoded (`_files`).

Recordings are stored as 16-bit codes, as the session format asks: 16-bit integer sources bit
for bit; any other sample format (24/32-bit integers, floats) is scaled per column so that its
largest magnitude is full scale and rounded (quantization noise 98 dB below that peak, far
below any microphone's own); the factor (codes per source unit) is kept per column in the
recording's meta, `import_scale`.
"""

from ._session import Prepared, check_import, import_session, prepare
from ._spec import MAX_POSES, MAX_SPEC_BYTES, ImportSpec, ImportSpecError, load_spec

__all__ = ["MAX_POSES", "MAX_SPEC_BYTES", "ImportSpec", "ImportSpecError", "Prepared",
           "check_import", "import_session", "load_spec", "prepare"]
