"""A firmware's words: the printer's statements said as one firmware's profile says them."""

from collections.abc import Iterable
from typing import Any

from fake_marlin.emulator.firmware.identity import Identity
from fake_marlin.emulator.firmware.profile import Profile
from fake_marlin.emulator.firmware.templates import fill
from fake_marlin.emulator.printer.statements import Heat, Statement


class Words:
    def __init__(self, profile: Profile, identity: Identity,
                 capabilities: tuple[tuple[str, bool], ...] | None = None) -> None:
        self._templates = profile.templates
        self._capabilities = profile.capabilities if capabilities is None else capabilities
        self._context: dict[str, object] = {
            "version": profile.version, "date": profile.date, "machine_type": profile.machine_type,
            "uuid": identity.uuid, "serial": identity.serial,
            "machine_name": identity.machine_name, "firmware": profile.name,
        }
        temperatures = profile.templates["temperatures"]
        self._special = {
            "greeting": self._greeting,
            "firmware_info": self._firmware_info,
            "temperatures": lambda values: self._fill(temperatures["one" if len(
                values["hotends"]) == 1 else "several"], self._heaters(values)),
            "auto_temperatures": lambda values: self._around(temperatures["auto"], values),
            "heating": lambda values: self._around(temperatures[
                "heating_bed" if values.get("heater") == "B" else "heating"], values),
            "position": lambda values: self._fill(self._templates["position"]["report"], values),
            "auto_position": lambda values: self._fill(self._templates["position"]["auto"], values),
            "verbatim": lambda values: [values["text"]],
        }

    def say(self, statement: Statement) -> list[str]:
        """The lines that say `statement` (none, where this firmware says nothing)."""
        special = self._special.get(statement.key)
        if special is not None:
            return special(statement.values)
        return self._fill(self._templates[statement.key], statement.values)

    def lines(self, statements: Iterable[Statement]) -> list[str]:
        return [line for statement in statements for line in self.say(statement)]

    def one_line(self, statement: Statement) -> str:
        """`statement` on one line (an `ok` line's answer): its lines joined by spaces."""
        return " ".join(self.say(statement))

    def _fill(self, templates: tuple[str, ...], values: Any) -> list[str]:
        context = {**self._context, **values}
        lines = []
        for template in templates:
            if template:
                lines.extend(fill(template, context).split("\n"))
        return lines

    def _heaters(self, values: Any) -> dict[str, object]:
        """The temperature report's values, with `each` and `each_power`: every hotend's part."""
        temperatures = self._templates["temperatures"]
        hotends: tuple[Heat, ...] = values["hotends"]
        each = " ".join(line for heat in hotends for line in self._fill(
            temperatures["each"], heat._asdict()))
        each_power = " ".join(line for heat in hotends for line in self._fill(
            temperatures["each_power"], heat._asdict()))
        return {**values, "each": each, "each_power": each_power}

    def _around(self, templates: tuple[str, ...], values: Any) -> list[str]:
        """A template around the temperature report (`{report}`): M155's, M109's."""
        report = " ".join(self.say(Statement("temperatures", values)))
        return self._fill(templates, {**values, "report": report})

    def _greeting(self, values: Any) -> list[str]:
        greeting = self._templates["greeting"]
        lines = self._fill(greeting["lines"], values)
        if values.get("sd"):
            lines += self._fill(greeting["sd"], values)
        return lines + self._fill(greeting["after"], values)

    def _firmware_info(self, values: Any) -> list[str]:
        info = self._templates["firmware_info"]
        lines = self._fill(info["lines"], values)
        for name, enabled in self._capabilities:
            lines += self._fill(info["capability"], {"name": name, "value": int(enabled)})
        return lines + self._fill(info["after"], values)
