# One image for the API (`bodyspace serve`) and the workers (`bodyspace worker`).
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    BODYSPACE_DATA_DIR=/data

WORKDIR /app
COPY pyproject.toml README.md ./
COPY core ./core
COPY service ./service
COPY worker ./worker
COPY openapi ./openapi
RUN pip install . \
    && useradd --create-home --uid 10001 bodyspace \
    && mkdir -p /data && chown bodyspace /data
USER bodyspace
VOLUME ["/data"]
EXPOSE 8000

# `bodyspace serve` by default; compose runs `bodyspace worker` from the same image.
CMD ["bodyspace", "serve", "--host", "0.0.0.0", "--port", "8000"]
