"""A certificate as a PDF (fpdf2): `to_pdf(certificate)` -> bytes, the same for the same certificate.

Every page carries the laboratory, the certificate number and "Page i of n"; the last ends with "End of
certificate". The DejaVu Sans fonts shipped in `fonts/` are embedded (as subsets). The PDF's creation date is the
date of issue (the signature's time) and its /ID is derived from the content, so the bytes depend on the records
and the log alone, not on when or where the certificate was written.
"""

from __future__ import annotations

import datetime as dt
import math
from pathlib import Path

from bench import __version__
from bench.cert.content import COVERAGE_PROBABILITY, DECISION_RULE, Certificate
from bench.cert.errors import CertError

FONTS = Path(__file__).parent / "fonts"
FONT = "DejaVu"
#: the PDF's /Subject: `bench cert check` finds the run (and the certificate's number) by it
SUBJECT_PREFIX = "turntable-bench certificate"


def _when(value: dt.datetime | None) -> str:
    return f"{value.isoformat(sep=' ', timespec='seconds')} UTC" if value is not None else "not recorded"


def _g(value: float, digits: int = 10) -> str:
    return f"{value:.{digits}g}"


def value_and_uncertainty(value: float, expanded: float | None) -> tuple[str, str]:
    """The value and its U as printed: U to two significant digits, the value to the same last decimal place."""
    if expanded is None or not math.isfinite(expanded) or expanded <= 0:
        return _g(value), "not estimated"
    last = math.floor(math.log10(expanded)) - 1          # the place of U's second significant digit
    if last < 0:
        return f"{value:.{-last}f}", f"{expanded:.{-last}f}"
    step = 10.0 ** last
    return f"{round(value / step) * step:.0f}", f"{round(expanded / step) * step:.0f}"


def subject(c: Certificate) -> str:
    return f"{SUBJECT_PREFIX} {c.number} run {c.record.run_id}"


def to_pdf(c: Certificate) -> bytes:
    """The certificate as a PDF (A4); CertError without fpdf2."""
    try:
        # optional (the `cert` extra): only when a PDF is written
        from fpdf import FPDF
        from fpdf.enums import XPos, YPos
    except ImportError as exc:
        raise CertError("writing a certificate's PDF needs fpdf2: pip install 'turntable-bench[cert]'") from exc

    class _Pdf(FPDF):
        def header(self) -> None:
            self.set_font(FONT, "B", 9)
            self.cell(0, 5, c.lab_name, new_x=XPos.LMARGIN, new_y=YPos.NEXT)
            self.set_font(FONT, "", 8)
            self.cell(0, 4, f"Certificate {c.number}", new_x=XPos.LMARGIN, new_y=YPos.NEXT)
            self.line(self.l_margin, self.get_y() + 1, self.w - self.r_margin, self.get_y() + 1)
            self.ln(4)

        def footer(self) -> None:
            self.set_y(-14)
            self.set_font(FONT, "", 8)
            self.cell(0, 4, f"Certificate {c.number}", new_x=XPos.LMARGIN, new_y=YPos.NEXT)
            self.cell(0, 4, f"Page {self.page_no()} of {{nb}}", align="R")

    pdf = _Pdf(format="A4")
    pdf.set_auto_page_break(True, margin=20)
    pdf.add_font(FONT, "", str(FONTS / "DejaVuSans.ttf"))
    pdf.add_font(FONT, "B", str(FONTS / "DejaVuSans-Bold.ttf"))
    pdf.set_creation_date(c.issued_utc.replace(tzinfo=dt.UTC))
    pdf.set_title(f"{c.title} {c.number}")
    pdf.set_subject(subject(c))
    pdf.set_creator(f"turntable-bench {__version__}")
    pdf.set_producer("fpdf2")
    pdf.set_lang("en")
    pdf.add_page()

    def heading(text: str) -> None:
        pdf.ln(2)
        pdf.set_font(FONT, "B", 10)
        pdf.cell(0, 6, text, new_x=XPos.LMARGIN, new_y=YPos.NEXT)
        pdf.set_font(FONT, "", 9)

    def field(name: str, value: str) -> None:
        pdf.set_font(FONT, "B", 9)
        pdf.cell(48, 5, name)
        pdf.set_font(FONT, "", 9)
        pdf.multi_cell(0, 5, value or "-", new_x=XPos.LMARGIN, new_y=YPos.NEXT)

    def text(value: str) -> None:
        pdf.multi_cell(0, 4.5, value, new_x=XPos.LMARGIN, new_y=YPos.NEXT)

    pdf.set_font(FONT, "B", 15)
    pdf.multi_cell(0, 8, c.title, new_x=XPos.LMARGIN, new_y=YPos.NEXT)
    pdf.set_font(FONT, "", 9)
    if not c.statement_of_conformity:
        text(f"This certificate is not a statement of conformity: {c.why_not}.")
    pdf.ln(1)
    field("Certificate number", c.number)
    field("Laboratory", c.lab_name)
    field("Address", c.lab_address + (f" ({c.country})" if c.country else ""))
    if c.lab_email:
        field("Contact", c.lab_email)
    field("Accreditation", c.accreditation_id or "not accredited")
    field("Location of calibration", "at the laboratory")
    field("Customer", c.customer)

    heading("Item calibrated")
    field("Item", c.item)
    field("IMU model", c.record.model)
    field("Serial number", c.record.serial)
    field("Date of receipt", "not recorded")

    heading("Method")
    text("Multi-position (static) and rate-turn calibration of an inertial measurement unit on a three-axis "
         "turntable; coefficients by least squares, with an uncertainty budget per the GUM (JCGM 100:2008).")
    field("Schedules", c.record.plan)
    field("Run", f"{c.record.run_id} ({c.record.mode or 'mode not recorded'}; operator "
                 f"{c.record.operator or 'not recorded'})")

    heading("Dates")
    started, finished = c.calibrated_utc
    field("Calibration", f"{_when(started)} to {_when(finished)}")
    field("Date of issue", _when(c.issued_utc))

    heading("Results")
    text(f"Each coefficient with its expanded uncertainty U = k u, coverage factor k = {_g(c.k, 4)} (a coverage "
         f"probability of about {COVERAGE_PROBABILITY:.0%} for a normal distribution), in the unit given; U to two "
         "significant digits, the value to the same decimal place. The DCC XML gives both unrounded, in SI units.")
    pdf.ln(1)
    with pdf.table(col_widths=(24, 24, 36, 26, 10, 46), text_align=("LEFT", "LEFT", "RIGHT", "RIGHT", "RIGHT", "LEFT"),
                   line_height=4.5, first_row_as_headings=True) as table:
        head = table.row()
        for name in ("Coefficient", "Quantity", "Value", "U", "k", "Unit"):
            head.cell(name)
        for row in c.rows:
            cells = table.row()
            cells.cell(row.name)
            cells.cell(row.title)
            for shown in value_and_uncertainty(row.value, row.expanded):
                cells.cell(shown)
            cells.cell(_g(row.k, 4))
            cells.cell(row.unit)

    heading("Statement of conformity and decision rule")
    field("Verdict", c.verdict)
    text(f"Decision rule: {DECISION_RULE}")
    checks = c.checks()
    if checks:
        pdf.ln(1)
        with pdf.table(col_widths=(46, 26, 30, 44, 16), text_align="LEFT", line_height=4.5,
                       first_row_as_headings=True) as table:
            head = table.row()
            for name in ("Check", "Value", "Limit", "Unit", "Passed"):
                head.cell(name)
            for check in checks:
                cells = table.row()
                value = check.get("value")
                cells.cell(str(check.get("name", "")))
                cells.cell(_g(value, 6) if isinstance(value, (int, float)) else "-")
                limit = check.get("limit")
                cells.cell(" to ".join(_g(v, 6) for v in limit) if isinstance(limit, list) else
                           _g(limit, 6) if isinstance(limit, (int, float)) else "-")
                cells.cell(str(check.get("unit", "")))
                cells.cell("yes" if check.get("passed") else "NO")
    else:
        text("No check ran: the result was not judged against acceptance limits.")

    heading("Metrological traceability")
    text("The measurements are traceable to the SI through the equipment below, each calibrated by the "
         "certificate named, valid until its due date.")
    pdf.ln(1)
    if c.equipment:
        with pdf.table(col_widths=(16, 22, 32, 16, 32, 22, 40), line_height=4.5,
                       first_row_as_headings=True) as table:
            head = table.row()
            for name in ("Tag", "Kind", "Make, model", "Serial", "Certificate", "Due", "Status"):
                head.cell(name)
            for item in c.equipment:
                cells = table.row()
                for value in (item.get("tag", ""), item.get("kind", ""),
                              f"{item.get('make', '')} {item.get('model', '')}".strip(), item.get("serial", ""),
                              item.get("certificate", ""), item.get("due_date", ""), c.in_date(item)):
                    cells.cell(value)
    else:
        text("No registered equipment was recorded for this run ([lab] equipment).")

    heading("Environmental conditions")
    field("IMU temperature", f"{c.imu_temperature_c:.2f} degC (mean over the run, from the IMU)"
          if c.imu_temperature_c is not None else "not recorded")
    field("Chamber", c.chamber)
    field("Site latitude", f"{c.site.latitude_deg:.6g} deg, height {c.site.height_m:.6g} m")
    field("Gravity", f"{c.site.gravity:.7f} m/s^2 ({c.gravity_source})")

    heading("Records")
    field("Software", f"turntable-bench {c.record.result_software_version} (result); "
                      f"{c.record.software_version} (run); certificate by {__version__}")
    field("Run log", c.log_name)
    field("Log SHA-256", c.log_sha256)
    field("Result", f"record {c.record.result_id} in the records database (the run's record of truth)")

    heading("Authorisation")
    if c.review is not None:
        same = c.signature is not None and c.signature.actor == c.review.actor
        field("Reviewed by", f"{c.review.actor}, {_when(c.review.at_utc)}"
              + (" (the same person as the signer)" if same else ""))
    if c.signature is not None:
        field("Authorised by", f"{c.signature.actor} ({c.signature.role}), {_when(c.signature.at_utc)}")
    else:
        field("Authorised by", "NOT SIGNED: not authorised")

    pdf.ln(3)
    text("The results relate only to the item calibrated. This certificate shall not be reproduced except in full "
         "without the written approval of the laboratory. It gives no recommendation of a calibration interval.")
    pdf.ln(2)
    pdf.set_font(FONT, "B", 9)
    pdf.cell(0, 5, "End of certificate", align="C")
    return bytes(pdf.output())


__all__ = ["SUBJECT_PREFIX", "subject", "to_pdf", "value_and_uncertainty"]
