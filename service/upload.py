"""The body of ``POST /meshes`` as a stream of file bytes: raw, or the multipart ``file``.

Multipart is parsed incrementally (python-multipart's streaming parser), so the file part
goes straight to the size-capped staging file like a raw body; nothing is spooled first.
"""

from __future__ import annotations

from collections.abc import AsyncIterator
from dataclasses import dataclass, field

from python_multipart.exceptions import MultipartParseError
from python_multipart.multipart import MultipartParser, parse_options_header
from starlette.requests import Request

from service.problems import BadRequestError

FILE_FIELD = "file"


@dataclass
class _Part:
    """State of the multipart part being parsed."""

    header_field: bytearray = field(default_factory=bytearray)
    header_value: bytearray = field(default_factory=bytearray)
    name: str | None = None
    filename: str | None = None
    done: bool = False
    seen_file: bool = False
    chunks: list[bytes] = field(default_factory=list)


class MultipartFile:
    """Streams the ``file`` part of a multipart body; ``filename`` once its headers are read."""

    def __init__(self, request: Request, boundary: bytes) -> None:
        self.request = request
        self.state = _Part()
        self.parser = MultipartParser(boundary, {
            "on_part_begin": self._begin,
            "on_header_field": self._field,
            "on_header_value": self._value,
            "on_header_end": self._header_end,
            "on_part_data": self._data,
            "on_part_end": self._end,
        })

    def _begin(self) -> None:
        self.state.name = None
        self.state.filename = None

    def _field(self, data: bytes, start: int, end: int) -> None:
        self.state.header_field += data[start:end]

    def _value(self, data: bytes, start: int, end: int) -> None:
        self.state.header_value += data[start:end]

    def _header_end(self) -> None:
        s = self.state
        if bytes(s.header_field).lower() == b"content-disposition":
            _, options = parse_options_header(bytes(s.header_value))
            s.name = options.get(b"name", b"").decode("utf-8", "replace")
            raw = options.get(b"filename")
            s.filename = None if raw is None else raw.decode("utf-8", "replace")
        s.header_field.clear()
        s.header_value.clear()

    def _data(self, data: bytes, start: int, end: int) -> None:
        if self.state.name == FILE_FIELD and not self.state.done:
            self.state.chunks.append(bytes(data[start:end]))

    def _end(self) -> None:
        if self.state.name == FILE_FIELD:
            self.state.done = True
            self.state.seen_file = True

    @property
    def filename(self) -> str | None:
        """The file part's file name (known once its headers went by)."""
        return self.state.filename if self.state.seen_file else None

    async def chunks(self) -> AsyncIterator[bytes]:
        """The bytes of the ``file`` part, as they arrive."""
        try:
            async for body in self.request.stream():
                self.parser.write(body)
                pending, self.state.chunks = self.state.chunks, []
                for chunk in pending:
                    yield chunk
            self.parser.finalize()
        except MultipartParseError as exc:
            raise BadRequestError(f"the multipart body is malformed ({exc}); send the model "
                                  f"as -F {FILE_FIELD}=@model.obj or as a raw body") from exc
        for chunk in self.state.chunks:
            yield chunk
        if not self.state.seen_file:
            raise BadRequestError(
                f"the multipart body has no part named '{FILE_FIELD}'; "
                f"send the model as -F {FILE_FIELD}=@model.obj")


def multipart_boundary(content_type: str) -> bytes | None:
    """The boundary of a ``multipart/form-data`` content type, else None."""
    kind, options = parse_options_header(content_type)
    if kind != b"multipart/form-data":
        return None
    boundary = options.get(b"boundary")
    if not boundary:
        raise BadRequestError("multipart/form-data without a boundary")
    return boundary
