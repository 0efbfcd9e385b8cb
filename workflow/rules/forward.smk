rule simulate:
    input:
        study=study_file,
    output:
        run=f"{RESULTS}/{{study}}/run.nc",
    log:
        f"{RESULTS}/logs/simulate_{{study}}.log",
    threads: 1
    resources:
        mem_mb=2000,
    shell:
        "liverinv -v simulate {input.study} --out {output.run} > {log} 2>&1"


rule plot_run:
    input:
        run=f"{RESULTS}/{{study}}/run.nc",
    output:
        fig=report(f"{RESULTS}/{{study}}/force_displacement.png", category="forward"),
        fields=f"{RESULTS}/{{study}}/fields.pvd",
    log:
        f"{RESULTS}/logs/plot_{{study}}.log",
    threads: 1
    shell:
        "liverinv plot {input.run} --out {output.fig} --fields {output.fields} > {log} 2>&1"
