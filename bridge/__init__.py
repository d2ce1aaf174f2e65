# SPDX-License-Identifier: GPL-3.0-or-later
"""The one place where bpy data and numpy arrays meet (``foreach_get``/``foreach_set``)."""
