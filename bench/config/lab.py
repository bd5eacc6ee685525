"""The `[lab]` section of a bench configuration: who calibrates, for whom, what, and with which equipment.

    [lab]
    name = "Example Calibration Lab"
    address = "1 Bench Street, Hangzhou"
    accreditation_id = "CNAS L0000"          # absent: not accredited
    country = "CN"                           # ISO 3166-1 alpha-2, for the DCC certificate
    email = "lab@example.com"
    certificate_number_pattern = "CAL-{year}-{run_id}"
    equipment = ["TT-01", "CH-01", "REF-T-01"]   # tags of `bench db equipment add`
    refuse_overdue_equipment = false         # true: a run with equipment past its due date does not start
    customer = "ACME Navigation"             # a run's customer; `bench run --customer` wins
    item = "gyro pack, asset 4711"           # the item calibrated; `bench run --item` wins

The section is optional: without it a run records no lab. Everything here is recorded in the run log's `lab`
metadata; the equipment is checked against the records database's register before the run moves anything.
"""

from __future__ import annotations

import re
import string
from dataclasses import dataclass

from bench.config.keys import allowed
from bench.config.reader import Table, describe, show

LAB_KEYS = allowed("lab")
#: what a certificate number pattern may name
NUMBER_FIELDS = ("year", "run_id", "serial")
#: the most equipment tags of one [lab] equipment list
MAX_EQUIPMENT = 50
#: the longest equipment tag (the register's column)
MAX_TAG = 64


@dataclass(frozen=True)
class LabConfig:
    """[lab]: the lab's identity, the run's customer and item, and the equipment the run uses (tags)."""

    name: str = ""
    address: str = ""
    accreditation_id: str = ""
    country: str = ""
    email: str = ""
    certificate_number_pattern: str = ""
    equipment: tuple[str, ...] = ()
    refuse_overdue_equipment: bool = False
    customer: str = ""
    item: str = ""

    def metadata(self) -> dict[str, str]:
        """The run log's `lab` record (without the equipment, which the run adds as the register has it)."""
        return {"name": self.name, "address": self.address, "accreditation_id": self.accreditation_id,
                "country": self.country, "email": self.email,
                "certificate_number_pattern": self.certificate_number_pattern, "customer": self.customer,
                "item": self.item}


def _pattern(t: Table) -> str:
    pattern = t.string("certificate_number_pattern", "")
    try:
        fields = [name for _, name, _, _ in string.Formatter().parse(pattern) if name is not None]
    except ValueError as exc:
        raise t.error("certificate_number_pattern", f"{exc}: write a field as {{year}}, a brace as {{{{") from None
    for name in fields:
        if name not in NUMBER_FIELDS:
            raise t.error("certificate_number_pattern",
                          f"unknown field {show('{' + name + '}')}: the fields are "
                          + ", ".join("{" + f + "}" for f in NUMBER_FIELDS))
    return pattern


def _country(t: Table) -> str:
    country = t.string("country", "")
    if country and not re.fullmatch(r"[A-Z]{2}", country):
        raise t.error("country", f"must be an ISO 3166-1 alpha-2 code, two capital letters (\"CN\"), "
                                 f"got {show(country)}")
    return country


def _equipment(t: Table) -> tuple[str, ...]:
    value = t.get("equipment", [])
    if not isinstance(value, list) or len(value) > MAX_EQUIPMENT:
        raise t.error("equipment", f"must be a list of at most {MAX_EQUIPMENT} equipment tags, got {describe(value)}")
    tags: list[str] = []
    for tag in value:
        if not isinstance(tag, str) or not tag.strip() or len(tag) > MAX_TAG:
            raise t.error("equipment", f"each tag must be a non-empty string of at most {MAX_TAG} characters, "
                                       f"got {describe(tag)}")
        if tag in tags:
            raise t.error("equipment", f"tag {show(tag)} is listed twice")
        tags.append(tag)
    return tuple(tags)


def lab_config(t: Table) -> LabConfig:
    """The checked [lab] section (every key optional)."""
    return LabConfig(name=t.string("name", ""), address=t.string("address", ""),
                     accreditation_id=t.string("accreditation_id", ""), country=_country(t),
                     email=t.string("email", ""),
                     certificate_number_pattern=_pattern(t), equipment=_equipment(t),
                     refuse_overdue_equipment=t.boolean("refuse_overdue_equipment", False),
                     customer=t.string("customer", ""), item=t.string("item", ""))


__all__ = ["LAB_KEYS", "NUMBER_FIELDS", "LabConfig", "lab_config"]
