"""Fast typed CDR codecs for the types of the package's IDL: the registry.

The codecs themselves are generated from the IDL's types by ``automotive/cyclone/codecgen.py`` (run by
``scripts/generate-types``) into ``automotive/types/codecs.py`` (which imports nothing of the project but the types:
its helpers are generated into it); nothing here is written per type. A codec encodes a
sample of its type into exactly the bytes Cyclone DDS Python's serializer makes (the 4-byte encapsulation header, then
XCDR1 or XCDR2 as asked, no trailing padding: the writer pads), and decodes such bytes (XCDR1 or XCDR2, either byte
order) into the generated dataclass, much faster: fixed-size members are packed and unpacked with precompiled
``struct`` formats, sequences of fixed-size structs in bulk.

- :func:`codec_for` gives the codec of a type (or None: then use Cyclone's serializer).
- ``codec.decode(data)`` is a function bytes -> dataclass that raises :class:`CodecError` (one line naming the type
  and what is wrong) on malformed input; it never reads past the buffer. ``codec.decode(data, views=True)`` gives
  sequences of fixed-size structs (the vision objects, the fused object list) as read-only numpy structured arrays
  viewing ``data``, without building one object per element; ``codec.element_dtype(member)`` is their dtype.
- ``codec.encode(sample, xcdr2=None, big_endian=False)`` also accepts such a numpy array (of that dtype, or with the
  same field names) for those members. An over-bound sequence or string raises the same
  :class:`~automotive.cyclone.bounds.BoundError` as :func:`automotive.cyclone.bounds.check`.

The codecs import nothing private from cyclonedds. Plugging them into Cyclone's own serialize/deserialize (so that
``DataWriter.write`` and ``DataReader.take`` use them) is ``automotive.cyclone.codec_hook``'s job, behind the version
gate.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from automotive.cyclone import bounds
from automotive.types import codecs as generated

if TYPE_CHECKING:
    import numpy as np

__all__ = ["Codec", "CodecError", "OverBound", "codec_for", "codecs", "numpy_if_loaded"]


CodecError = generated.CodecError  # bytes that are not a valid sample of the type, or a value it cannot encode
OverBound = generated.OverBound  # inside the generated encoders; turned into a BoundError here
# numpy's module if the process has imported it, else None: how to tell a numpy value without importing numpy
numpy_if_loaded: Callable[[], Any] = generated.numpy_if_loaded
generated.EXTRA_BOUNDS = bounds.EXTRA_BOUNDS  # the one registry of the extra bounds (set_extra_bound changes it)

Encoder = Callable[[Any], bytes]
Decoder = Callable[[Any, int, int, bool], tuple[Any, int]]

# The encapsulation identifiers (byte 1 of the header; byte 0 is 0): bit 0 = little endian, above 3 = XCDR2.
_LITTLE = 1


class Codec:
    """The generated encoder and decoders of one type (see the module's docstring)."""

    def __init__(self, data_type: type, label: str, default_xcdr2: bool,
                 encoders: dict[tuple[bool, bool], Encoder], decoders: dict[tuple[bool, bool], Decoder],
                 element_dtypes: dict[str, Any], has_octet_blocks: bool):
        self.data_type = data_type
        self.label = label
        self.default_xcdr2 = default_xcdr2  # what Cyclone writes when no representation is asked for
        self._encoders = encoders  # (xcdr2, big endian) -> encoder
        self._decoders = decoders  # (xcdr2, big endian) -> decoder of the body
        # little-endian XCDR1 dtypes of the members decoded as numpy views, made at first use (generated LazyDtype)
        self._element_dtypes = element_dtypes
        self.view_members = tuple(element_dtypes)
        # The type holds octet sequences or arrays (moved as blocks of bytes): automotive.fastpath handles it too.
        self.has_octet_blocks = has_octet_blocks

    def __repr__(self) -> str:
        return f"Codec({self.label})"

    def encode(self, sample: Any, xcdr2: bool | None = None, big_endian: bool = False) -> bytes:
        """The serialized sample with its encapsulation header, as Cyclone's ``IDL.serialize`` makes it."""
        encoder = self._encoders[(self.default_xcdr2 if xcdr2 is None else bool(xcdr2), big_endian)]
        try:
            return encoder(sample)
        except OverBound as over:
            raise self._bound_error(sample, over) from None
        except CodecError:
            raise
        except Exception as error:  # struct.error, TypeError, AttributeError, OverflowError...: a bad value
            raise CodecError(f"{self.label}: cannot encode {type(sample).__name__} ({error})") from None

    def _bound_error(self, sample: Any, over: Exception) -> Exception:
        """The BoundError bounds.check gives for this sample (with the member's full path), else ours."""
        try:
            bounds.check(sample)
        except bounds.BoundError as error:
            return error
        return bounds.BoundError(str(over))

    def decode(self, data: Any, views: bool = False) -> Any:
        """The sample in ``data`` (bytes-like, with its encapsulation header; trailing padding is ignored)."""
        try:
            size = len(data)
            if size < 4:
                raise CodecError(f"{self.label}: {size} bytes, too short for a serialized sample")
            kind = data[1]
            decoder = self._decoders[(kind > 3, not kind & _LITTLE)]
            sample, _ = decoder(data, 4, size, views)
            return sample
        except CodecError as error:
            if str(error).startswith(self.label):
                raise
            raise CodecError(f"{self.label}: {error}") from None  # a nested type's error: say whose sample it was
        except Exception as error:  # struct.error on a short buffer, UnicodeDecodeError, TypeError on non-bytes...
            raise CodecError(f"{self.label}: malformed sample ({type(error).__name__}: {error})") from None

    def with_views(self, sample: Any) -> Any:
        """``sample`` with its sequences of fixed-size structs as numpy arrays (a copy made through the bytes)."""
        return self.decode(self.encode(sample), views=True)

    def with_dataclasses(self, sample: Any) -> Any:
        """``sample`` with numpy arrays in its sequences of fixed-size structs turned into dataclasses."""
        numpy = numpy_if_loaded()
        if numpy is not None and any(isinstance(getattr(sample, member), numpy.ndarray)
                                     for member in self.view_members):
            return self.decode(self.encode(sample))
        return sample

    def element_dtype(self, member: str) -> np.dtype[Any]:
        """The numpy dtype (little endian) of the elements of ``member``, a sequence of fixed-size structs."""
        try:
            lazy = self._element_dtypes[member]
        except KeyError:
            raise KeyError(f"{self.label}.{member} is not a sequence of fixed-size structs "
                           f"(those are: {', '.join(self._element_dtypes) or 'none'})") from None
        dtype: np.dtype[Any] = lazy.get()
        return dtype


_CODECS: dict[type, Codec] = {data_type: Codec(data_type, *parts)
                              for data_type, parts in generated.CODEC_PARTS.items()}


def codecs() -> dict[type, Codec]:
    """Every generated codec, by type."""
    return _CODECS


def codec_for(data_type: type) -> Codec | None:
    """The generated codec of ``data_type``, or None when there is none (use Cyclone's serializer)."""
    return _CODECS.get(data_type)
