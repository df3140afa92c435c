"""rovlink: teleoperation of an underwater ROV over a ~1.9 kbit/s radio or
acoustic link.

The project's folders install under this one import name (setuptools'
package-dir in pyproject.toml): ``rovlink.link`` is ``link/``,
``rovlink.debt`` is ``debt/``, ``rovlink.rov`` is ``rov/``, ``rovlink.console``
is ``console/`` and ``rovlink.assets`` is ``assets/``.  This package itself
holds only the command's dispatcher (``rovlink.cli``, the ``rovlink`` entry
point) and the small kit every command shares (``rovlink.command``), so that
the ROV side runs without the console, let alone its extra.
"""

__version__ = "0.1.0"
