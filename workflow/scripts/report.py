from selfsense import stages

with stages.logged(snakemake.log[0]):  # noqa: F821
    print(stages.report(snakemake.params.dataset_dir, snakemake.params.results_dir, snakemake.output[0],  # noqa: F821
                        config=snakemake.params.run_config))  # noqa: F821
