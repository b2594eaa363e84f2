# Image for `artitwin worker` (infra/compose.yaml). Built from the repository root.
FROM python:3.11-slim
RUN apt-get update && apt-get install -y --no-install-recommends libgl1 libgomp1 && rm -rf /var/lib/apt/lists/*
WORKDIR /src
COPY . /src
RUN pip install --no-cache-dir --extra-index-url https://download.pytorch.org/whl/cpu . prefect-dask s3fs
ENV PREFECT_SERVER_ANALYTICS_ENABLED=false
CMD ["artitwin", "worker"]
