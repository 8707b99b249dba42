{{/* Names are fixed (not release-prefixed) where other parts refer to them: one toolkit per cluster. */}}
{{- define "netapp-toolkit.name" -}}netapp-toolkit{{- end -}}

{{- define "netapp-toolkit.labels" -}}
app.kubernetes.io/part-of: netapp-toolkit
app.kubernetes.io/instance: {{ .Release.Name }}
app.kubernetes.io/version: {{ .Chart.AppVersion | quote }}
app.kubernetes.io/managed-by: {{ .Release.Service }}
helm.sh/chart: {{ printf "%s-%s" .Chart.Name .Chart.Version }}
{{- end -}}

{{- define "netapp-toolkit.image" -}}
{{ .Values.image.repository }}:{{ .Values.image.tag | default .Chart.AppVersion }}
{{- end -}}

{{- define "netapp-toolkit.netappNamespace" -}}
{{ .Values.middleware.netappNamespace | default .Release.Namespace }}
{{- end -}}

{{- define "netapp-toolkit.robotsSecret" -}}
{{ .Values.robots.existingSecret | default (printf "%s-middleware-robots" .Release.Name) }}
{{- end -}}

{{- define "netapp-toolkit.tokenKeySecret" -}}
{{ .Values.middleware.tokenKeySecret | default (printf "%s-middleware-token-key" .Release.Name) }}
{{- end -}}

{{- define "netapp-toolkit.rolloutTokenSecret" -}}
{{ .Values.operator.rollouts.tokenSecret | default (printf "%s-operator-rollout-token" .Release.Name) }}
{{- end -}}
