"""Input at the edge: TOML files into validated typed tables, command lines, and their one-line errors.

The bottom package: it imports nothing from the project, and every package may import it.

* :mod:`config_tables.errors`        :class:`~config_tables.errors.ConfigError` (one line: file, field, what is
                                     allowed) and :class:`~config_tables.errors.FieldProblem`; no pydantic, so
                                     a command line catches them without loading the tables;
* :mod:`config_tables.toml_file`     read a TOML file (standard library only);
* :mod:`config_tables.models`        :class:`~config_tables.models.ConfigModel`, the pydantic base of every
                                     configuration table, its field annotations and ``parse`` / ``load``;
* :mod:`config_tables.messages`      a pydantic validation error as the one-line message;
* :mod:`config_tables.command_line`  the one-line usage-error parser of every command line (exit status 2).
"""
