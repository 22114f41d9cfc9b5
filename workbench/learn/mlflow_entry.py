"""What MLflow runs to build a logged leg model (MLflow's "models from code": nothing pickled).

``mlflow.pyfunc.log_model(python_model=<this file>, artifacts={"leg_model": <model folder>})``
copies this file into the MLflow model; loading executes it, and MLflow hands the model folder
to :meth:`workbench.learn.pyfunc.LearnedLegPyfunc.load_context`.
"""

from mlflow.models import set_model

from workbench.learn.pyfunc import LearnedLegPyfunc

set_model(LearnedLegPyfunc())
