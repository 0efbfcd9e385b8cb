from snakemake.utils import min_version

min_version("8.0")


configfile: "config/config.yaml"


include: "workflow/rules/common.smk"
include: "workflow/rules/forward.smk"


rule all:
    input:
        expand(f"{RESULTS}/{{study}}/force_displacement.png", study=list(STUDIES)),
