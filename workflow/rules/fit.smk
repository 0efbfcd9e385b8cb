# Fits (law x seed x method), gathered into one Dataset; tables and figures from files.


rule fit:
    input:
        unpack(fit_job_inputs),
    output:
        f"{RESULTS}/{{study}}/fits/{{law}}_{{seed}}_{{method}}.nc",
    params:
        options=fit_options,
        checkpoint=f"{RESULTS}/{{study}}/checkpoints/{{law}}_{{seed}}_{{method}}",
    log:
        f"{RESULTS}/logs/{{study}}/fit_{{law}}_{{seed}}_{{method}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/{{study}}/fit_{{law}}_{{seed}}_{{method}}.tsv"
    conda:
        "../envs/liverinv.yaml"
    priority: fit_priority
    threads: 1
    resources:
        mem_mb=4000,
        runtime=240,
    shell:
        "liverinv fit --bundle {input.bundle} --flow {input.flow} --mesh {input.mesh} {params.options} "
        "--checkpoint {params.checkpoint} --fresh-checkpoint --keep-going --out {output} > {log} 2>&1"


rule gather:
    input:
        study=lambda wc: str(STUDY[wc.study].path),
        fits=fit_files,
    output:
        f"{RESULTS}/{{study}}/fits.nc",
    params:
        folder=lambda wildcards, input: os.path.dirname(input.fits[0]),
    log:
        f"{RESULTS}/logs/{{study}}/gather.log",
    benchmark:
        f"{RESULTS}/benchmarks/{{study}}/gather.tsv"
    conda:
        "../envs/liverinv.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    shell:
        "liverinv gather {input.study} --name {wildcards.study} --fits-dir {params.folder} --out {output} > {log} 2>&1"


rule tables:
    input:
        f"{RESULTS}/{{study}}/fits.nc",
    output:
        csv=report(f"{RESULTS}/{{study}}/table.csv", caption="../report/table.rst", category="tables"),
        md=f"{RESULTS}/{{study}}/table.md",
        ranking=report(f"{RESULTS}/{{study}}/ranking.csv", caption="../report/ranking.rst", category="tables"),
    log:
        f"{RESULTS}/logs/{{study}}/tables.log",
    benchmark:
        f"{RESULTS}/benchmarks/{{study}}/tables.tsv"
    conda:
        "../envs/liverinv.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,
    shell:
        "liverinv tables {input} --csv {output.csv} --md {output.md} --ranking-csv {output.ranking} > {log} 2>&1"


rule convergence:
    input:
        f"{RESULTS}/{{study}}/fits.nc",
    output:
        report(f"{RESULTS}/{{study}}/figures/convergence_{{law}}.png", caption="../report/convergence.rst",
               category="convergence", subcategory="{study}"),
    log:
        f"{RESULTS}/logs/{{study}}/convergence_{{law}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/{{study}}/convergence_{{law}}.tsv"
    conda:
        "../envs/liverinv.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,
    shell:
        "liverinv figures {input} --convergence {wildcards.law} --out {output} > {log} 2>&1"


rule figures:
    input:
        unpack(fit_inputs),
        fits=f"{RESULTS}/{{study}}/fits.nc",
        fit_files=fit_files,
    output:
        indenter=report(f"{RESULTS}/{{study}}/figures/indenter.png", caption="../report/indenter.rst",
                        category="fits", subcategory="{study}"),
        velocities=report(f"{RESULTS}/{{study}}/figures/velocities.png", caption="../report/velocities.rst",
                          category="fits", subcategory="{study}"),
        fields=f"{RESULTS}/{{study}}/figures/fields.pvd",
    params:
        folder=lambda wildcards, input: os.path.dirname(input.fit_files[0]),
        nodes=lambda wc: STUDY[wc.study].spec.get("figures", {}).get("nodes", 4),
        slice_y=lambda wc: STUDY[wc.study].spec.get("figures", {}).get("slice_y_m", 0.0),
    log:
        f"{RESULTS}/logs/{{study}}/figures.log",
    benchmark:
        f"{RESULTS}/benchmarks/{{study}}/figures.tsv"
    conda:
        "../envs/liverinv.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    shell:
        "liverinv figures {input.fits} --fits-dir {params.folder} --bundle {input.bundle} --flow {input.flow} "
        "--mesh {input.mesh} --nodes {params.nodes} --slice-y {params.slice_y} "
        "--indenter {output.indenter} --velocities {output.velocities} --fields {output.fields} > {log} 2>&1"


rule discover:
    input:
        unpack(fit_inputs),
    output:
        nc=f"{RESULTS}/{{study}}/discovery.nc",
        fig=report(f"{RESULTS}/{{study}}/figures/discovery.png", caption="../report/discovery.rst",
                   category="diagnosis", subcategory="{study}"),
    params:
        options=discover_options,
        folder=lambda wildcards, output: os.path.dirname(output.fig),
    log:
        f"{RESULTS}/logs/{{study}}/discover.log",
    benchmark:
        f"{RESULTS}/benchmarks/{{study}}/discover.tsv"
    conda:
        "../envs/liverinv.yaml"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=240,
    shell:
        "liverinv discover --bundle {input.bundle} --flow {input.flow} --mesh {input.mesh} {params.options} "
        "--out {output.nc} --figures {params.folder} > {log} 2>&1"
