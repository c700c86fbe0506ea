"""What counts as the command on a G-code line. Host and printer must agree on this exactly:
it is what the host sends and what the printer's journal records."""

import re

_PAREN_COMMENT = re.compile(r"\([^)]*\)")


def strip_comment(line: str) -> str:
    """The command without `;` and `( )` comments or surrounding white space."""
    return remove_paren_comments(line.split(";", 1)[0]).strip()


def remove_paren_comments(text: str) -> str:
    return _PAREN_COMMENT.sub("", text)
