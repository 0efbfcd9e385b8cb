from pathlib import Path

from snakemake.utils import validate

validate(config, schema="../schemas/config.schema.yaml")

# every study file is validated before any rule runs
from liverinv.study import load_study

STUDIES = config["studies"]
for _name, _path in STUDIES.items():
    load_study(_path)

RESULTS = config.get("results", "results")


def study_file(wildcards):
    return STUDIES[wildcards.study]
