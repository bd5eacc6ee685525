"""What a walk over a log found damaged or missing, told one line each (`Damage.describe`)."""

from __future__ import annotations

from dataclasses import dataclass, field


def _fmt_range(start_ns: int, end_ns: int) -> str:
    return f"log time {start_ns / 1e9:.3f}..{end_ns / 1e9:.3f} s"


_MAX_DESCRIBE = 600   # characters of a damage line


@dataclass
class Damage:
    """One damaged or missing part of a log."""

    kind: str                    # "chunk", "truncated", "corrupt", "no_summary", "attachment", "message", "metadata"
    offset: int                  # byte offset of the damaged record (or of the end of the file)
    reason: str
    start_ns: int | None = None  # log-time range of a lost chunk, when its header was readable
    end_ns: int | None = None
    lost: dict[str, int] = field(default_factory=dict)   # topic -> messages lost, when known
    chunks: int = 1              # consecutive chunks refused for the same reason, told as one
    last_offset: int = 0         # byte offset of the last of them

    def describe(self) -> str:
        """One line (whatever the reason quotes from the file)."""
        return " ".join(self._describe().split())[:_MAX_DESCRIBE]

    def _describe(self) -> str:
        where = ""
        if self.start_ns is not None and self.end_ns is not None:   # a range is known whole or not at all
            where = f" ({_fmt_range(self.start_ns, self.end_ns)})"
        if self.kind == "chunk":
            what = (", ".join(f"{n} on {t}" for t, n in sorted(self.lost.items())) if self.lost
                    else "count unknown")
            if self.chunks > 1:
                return (f"{self.chunks} chunks at bytes {self.offset}..{self.last_offset}{where}, each: "
                        f"{self.reason}; their messages lost ({what})")
            return f"chunk at byte {self.offset}{where}: {self.reason}; its messages lost ({what})"
        if self.kind == "truncated":
            return f"truncated after byte {self.offset}: {self.reason}{where}"
        if self.kind in ("no_summary", "metadata"):
            return self.reason
        return f"byte {self.offset}: {self.reason}{where}"
