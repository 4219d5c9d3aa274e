"""The built-in ``bullet_tabletop`` tasks (registered on import)."""

from . import articulated, contact, rigid

__all__ = ["articulated", "contact", "rigid"]
