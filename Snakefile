# liverinv studies: `snakemake --cores 2 --config study=NAME` (default: quick).
# Studies are listed in config/config.yaml; their keys in config/README.md.
from snakemake.utils import min_version

min_version("8.0")


configfile: "config/config.yaml"


include: "workflow/rules/common.smk"
include: "workflow/rules/data.smk"
include: "workflow/rules/fit.smk"


rule all:
    input:
        [f for study in SELECTED for f in study_outputs(study)],
    default_target: True
