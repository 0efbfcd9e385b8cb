# Data: meshes, the truth simulation, its ultrasound rendering, tracking.


rule mesh:
    output:
        f"{RESULTS}/meshes/{{preset}}.msh",
    log:
        f"{RESULTS}/logs/mesh_{{preset}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/mesh_{{preset}}.tsv"
    conda:
        "../envs/liverinv.yaml"
    priority: DATA_PRIORITY
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,
    shell:
        "python -m liverinv.meshgen {output} --preset {wildcards.preset} > {log} 2>&1"


rule truth:
    input:
        unpack(truth_inputs),
    output:
        f"{RESULTS}/data/{{dataset}}/truth.nc",
    params:
        mesh=truth_mesh_option,
    log:
        f"{RESULTS}/logs/truth_{{dataset}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/truth_{{dataset}}.tsv"
    conda:
        "../envs/liverinv.yaml"
    priority: DATA_PRIORITY
    threads: 2
    resources:
        mem_mb=4000,
        runtime=60,
    shell:
        "liverinv -v synthesize {input.study} {params.mesh} --truth-only --truth-out {output} > {log} 2>&1"


rule render:
    input:
        unpack(truth_inputs),
        truth=f"{RESULTS}/data/{{dataset}}/truth.nc",
    output:
        f"{RESULTS}/data/{{dataset}}/bundle.h5",
    params:
        mesh=truth_mesh_option,
    log:
        f"{RESULTS}/logs/render_{{dataset}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/render_{{dataset}}.tsv"
    conda:
        "../envs/liverinv.yaml"
    priority: DATA_PRIORITY
    threads: 1
    resources:
        mem_mb=4000,
        runtime=60,
    shell:
        "liverinv -v synthesize {input.study} {params.mesh} --truth-in {input.truth} --out {output} > {log} 2>&1"


rule track:
    input:
        unpack(track_inputs),
    output:
        flow=f"{RESULTS}/data/{{dataset}}/flow_{{tracking}}.nc",
        picture=report(f"{RESULTS}/data/{{dataset}}/flow_{{tracking}}.png",
                       caption="../report/tracking.rst", category="data"),
    params:
        options=track_options,
    log:
        f"{RESULTS}/logs/track_{{dataset}}_{{tracking}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/track_{{dataset}}_{{tracking}}.tsv"
    conda:
        "../envs/liverinv.yaml"
    priority: DATA_PRIORITY
    threads: 2
    resources:
        mem_mb=4000,
        runtime=60,
    shell:
        "LIVERINV_THREADS={threads} liverinv -v track {input.bundle} --mesh {input.mesh} {params.options} --out {output.flow} "
        "--picture {output.picture} > {log} 2>&1"
