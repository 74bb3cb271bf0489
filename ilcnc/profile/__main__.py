"""``python -m ilcnc.profile``: print the profile reference (``docs/profile.md``'s generated block)."""

from ilcnc.profile.docs import schema_markdown

print(schema_markdown(), end="")
