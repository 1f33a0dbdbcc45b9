"""The release version: the one place it is written (pyproject.toml reads it from here).

Semantic versioning; CHANGELOG.md says what each release changed and CONTRIBUTING.md how
a release is cut.
"""

__version__ = "0.2.0"
