"""Prints what the fuzz tests ran: readers and examples (:mod:`fuzzing` holds the profiles)."""

from fuzzing import EXAMPLES, PROFILE


def pytest_terminal_summary(terminalreporter):
    if EXAMPLES:
        terminalreporter.write_line(
            f"fuzz ({PROFILE} profile): {len(EXAMPLES)} readers, {sum(EXAMPLES.values())} examples "
            "(" + ", ".join(f"{name} {count}" for name, count in sorted(EXAMPLES.items())) + ")")
