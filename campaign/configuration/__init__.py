"""Campaign configuration: each TOML file validated at the edge into one frozen model.

* :mod:`.campaign_file`  a campaign file (site + ``[campaign]``, ``[sensors]``, ``[scene]`` ...) and its hash;
* :mod:`.estimators`     ``[estimator]`` (calibration products) and ``[[estimators]]``;
* :mod:`.execution`      ``[execution]``: where the cases run (never part of the hash);
* :mod:`.sweep_file`     a sweep file: base campaign plus axes -> one campaign config per point;
* :mod:`.schemas`        the JSON Schemas of every table (``campaign schema``).
"""
