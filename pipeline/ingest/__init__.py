"""The ingest stage: raw Arduino CSV captures -> schema-checked Parquet and MCAP, with units.

Entry points for other stages:
  ``stage.ingest_recording(csv_path, processed, *, config=None) -> IngestResult``
      ``.runs`` (``RunPaths``, one per kept segment), ``.report`` (dict, also in each run's
      ``ingest_report.json``), ``.tables`` (run name -> signals DataFrame).
  ``stage.ingest_capture(data, cfg, source, stem) -> (list[RunData], report)``: the pure core,
      ``read_capture`` (tables; every refusal raised here) then ``capture_report``.
  ``stage.ingest_signals(data, cfg, source, stem, processed) -> (runs, report, list[RunPaths])``:
      the pure core with each run's signals.parquet written in a worker thread beside the report.

Modules: ``plain`` (fast path for clean captures; ``plain_kernel``, its compiled reader for
large ones, which writes the signals columns themselves when every row keeps the range rules),
``parse`` (general line-by-line path, quarantine, re-framing), ``segments`` (range rules, time
order, resets), ``timing``, ``convert`` (units, zero_v "auto"),
``mcap_bulk`` (vectorised MCAP writer; ``records_kernel``, its compiled record join),
``write`` (files, atomic), ``compile`` (the numba loops compiled at set-up), ``cli`` (``pdr ingest``).
"""
