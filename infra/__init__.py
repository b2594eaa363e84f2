"""What deploys and stores: the content-addressed artifact store (``infra.store``) and deployment
files (prefect.yaml, compose files, work-pool templates)."""
